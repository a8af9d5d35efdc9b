"""Sampling priorities of CMCL and its baselines (ALGORITHM.md §3.3, §3.5, §3.6, A1, A7, A8).

Where it sits in the flow: the replay buffer (`cmcl.replay.buffer`) keeps raw per-agent score columns (teacher
difficulty c, ICM curiosity ρ, learner |δ|). Each time λ or the scores change it calls the functions here to
turn those columns into one priority column per agent, which the per-agent samplers (`cmcl.replay.sampler`) draw from.

Shape convention: score matrices are ``[M, A]`` -- M buffer rows (the valid rows of the buffer) by A agents,
the same layout as the replay's score columns ``float32[capacity, N]``. One-dimensional ``[M]`` input is
treated as a single agent. All outputs are float64.

Everything is pure numpy; no function emits NaN or a RuntimeWarning for valid input (each KP branch is
evaluated only on the elements it applies to).
"""

from __future__ import annotations

import numpy as np

EPS_P = 1e-6  # ε_p: priority floor keeping every transition reachable
LAM_MAX = 1.0  # largest admissible curriculum factor (KP is undefined above 1)
STD_EPS = 1e-8  # added to the std in curiosity normalisation
# sampling controls (config teams.<team>.priority.difficulty_transform): "none" = the method,
# "reversed" = anti-curriculum (ĉ -> 1 − ĉ before KP), "permuted" = priorities shuffled across rows
# (`permute_priorities`)
DIFFICULTY_TRANSFORMS = ("none", "permuted", "reversed")


def _finite_array(name: str, x) -> np.ndarray:
    """`x` as a float64 array; ValueError naming `name` if it holds NaN or ±inf."""
    arr = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        bad = arr[~np.isfinite(arr)].ravel()[0]
        raise ValueError(f"{name} must be finite, got {bad!r}")
    return arr


def _check_lam(lam: float, lam_max: float) -> float:
    """Validate 0 < lam <= lam_max <= 1; returns lam as float."""
    if not (0.0 < lam_max <= LAM_MAX):
        raise ValueError(f"lam_max must lie in (0, {LAM_MAX}], got {lam_max!r}")
    lam_f = float(lam)
    if not (0.0 < lam_f <= lam_max):  # also false for NaN
        raise ValueError(f"lam must lie in (0, {lam_max}], got {lam!r}")
    return lam_f


def kfold_priority(c_hat, lam: float, lam_max: float = LAM_MAX) -> np.ndarray:
    """K-fold priority KP(ĉ, λ) of eq. (12), §3.3.

    Args:
        c_hat: normalised difficulty, any shape; clamped to [0, 1]; must be finite.
        lam: curriculum factor λ, 0 < λ <= lam_max (ValueError otherwise).
        lam_max: cap on λ, at most 1.
    Returns:
        float64 array of c_hat's shape with values in [0, 1]:
        exp(ĉ−λ) for ĉ <= λ; log(ĉ−2λ+1)/log(1−λ) for λ < ĉ < 2λ; 0 for ĉ >= 2λ.
    """
    lam_f = _check_lam(lam, lam_max)
    c = np.clip(_finite_array("c_hat", c_hat), 0.0, 1.0)
    out = np.zeros_like(c)
    low = c <= lam_f
    out[low] = np.exp(c[low] - lam_f)
    mid = ~low & (c < 2.0 * lam_f)
    if np.any(mid):  # implies lam < 1, so log1p(-lam) is finite and negative
        out[mid] = np.log1p(c[mid] - 2.0 * lam_f) / np.log1p(-lam_f)
    return np.clip(out, 0.0, 1.0, out=out)


def curiosity_priority(rho) -> np.ndarray:
    """Curiosity priority CP(ρ) = 1 − exp(−ρ²/10) of eq. (19), §3.5.

    Args:
        rho: curiosity values (raw or std-normalised), any shape, finite and >= 0.
    Returns:
        float64 array of rho's shape in [0, 1]. Values above 1e3 are treated as 1e3 (CP = 1 there) so
        squaring never overflows.
    """
    r = _finite_array("rho", rho)
    if np.any(r < 0):
        raise ValueError(f"rho must be >= 0, got {r[r < 0].ravel()[0]!r}")
    r = np.minimum(r, 1e3)
    return -np.expm1(-np.square(r) / 10.0)


def curriculum_index(kp, cp, eta: float) -> np.ndarray:
    """Curriculum index CI = KP + η·CP (eq. 8, §3.6), in [0, 1+η]; the sampling priority of a CMCL agent.

    Args:
        kp: KP values, any shape. cp: CP values, broadcastable to kp. eta: curiosity weight η >= 0.
    """
    eta_f = float(eta)
    if not (np.isfinite(eta_f) and eta_f >= 0.0):
        raise ValueError(f"eta must be finite and >= 0, got {eta!r}")
    return np.asarray(kp, dtype=np.float64) + eta_f * np.asarray(cp, dtype=np.float64)


def _as_columns(name: str, x) -> tuple[np.ndarray, bool]:
    """Return (float64 [M, A] array, was_1d)."""
    arr = _finite_array(name, x)
    if arr.ndim == 1:
        return arr[:, None], True
    if arr.ndim != 2:
        raise ValueError(f"{name} must have shape [M] or [M, A], got shape {arr.shape}")
    return arr, False


def normalise_difficulty(c, method: str = "rank") -> np.ndarray:
    """Per-agent difficulty normalisation ĉ (§3.3, A1).

    Args:
        c: raw difficulty, shape [M] or [M, A] (M valid buffer rows, A agents); finite, negatives clamped to 0.
        method: "max": ĉ = min(1, c / max_rows c) per column (0 where the column max is 0);
                "rank": ĉ = rank/(M−1) with ties sharing their lowest rank (so a constant column gives 0).
    Returns:
        float64 array of c's shape, values in [0, 1]. Invariant under multiplying c by a positive constant.
    """
    arr, flat = _as_columns("c", c)
    arr = np.maximum(arr, 0.0)
    if method == "max":
        colmax = arr.max(axis=0) if arr.shape[0] else np.zeros(arr.shape[1])
        safe = np.where(colmax > 0, colmax, 1.0)
        out = np.where(colmax > 0, np.minimum(arr / safe, 1.0), 0.0)
    elif method == "rank":
        out = np.zeros_like(arr)
        m = arr.shape[0]
        if m > 1:
            for a in range(arr.shape[1]):  # A is the number of agents (small)
                col = arr[:, a]
                out[:, a] = np.searchsorted(np.sort(col), col, side="left") / (m - 1)
    else:
        raise ValueError(f"method must be 'max' or 'rank', got {method!r}")
    return out[:, 0] if flat else out


def normalise_curiosity(rho, method: str = "std") -> np.ndarray:
    """Curiosity scale normalisation ρ̂ (§3.5, A7).

    Args:
        rho: raw curiosity, shape [M] or [M, A]; finite and >= 0.
        method: "std": ρ / (std over rows + 1e-8) per column; "raw": unchanged.
    Returns:
        float64 array of rho's shape.
    """
    arr, flat = _as_columns("rho", rho)
    if np.any(arr < 0):
        raise ValueError(f"rho must be >= 0, got {arr[arr < 0].ravel()[0]!r}")
    if method == "std":
        std = arr.std(axis=0) if arr.shape[0] else np.zeros(arr.shape[1])
        out = arr / (std + STD_EPS)
    elif method == "raw":
        out = arr.copy()
    else:
        raise ValueError(f"method must be 'std' or 'raw', got {method!r}")
    return out[:, 0] if flat else out


def sampling_probabilities(p, alpha: float) -> np.ndarray:
    """P(j) = p_j^α / Σ_k p_k^α (eq. 20), per column, dense over the buffer (the curriculum diagnostics read it;
    `cmcl.replay.sampler` holds the same p^α incrementally to draw from).

    Args:
        p: priorities, shape [M] or [M, A]; finite, >= 0, with a positive sum per column.
        alpha: sampling exponent α_s >= 0 (0 gives uniform sampling over the items with p > 0; an item
            with p = 0 has probability 0 for every α, as in `cmcl.replay.sampler`).
    Returns:
        float64 array of p's shape; each column sums to 1.
    """
    alpha_f = float(alpha)
    if not (np.isfinite(alpha_f) and alpha_f >= 0.0):
        raise ValueError(f"alpha must be finite and >= 0, got {alpha!r}")
    arr = _finite_array("p", p)
    if np.any(arr < 0):
        raise ValueError(f"p must be >= 0, got {arr[arr < 0].ravel()[0]!r}")
    w = (arr > 0).astype(np.float64) if alpha_f == 0 else np.power(arr, alpha_f)
    total = w.sum(axis=0)
    if np.any(total <= 0):
        raise ValueError("p must have a positive sum (after the exponent alpha) in every column")
    return w / total


def _over_scored(values: np.ndarray, scored: np.ndarray, normalise) -> np.ndarray:
    """normalise applied over the scored rows only (float[M] -> float64[M], 0 on unscored rows)."""
    if scored.all():  # the common case: no gather/scatter
        return normalise(values)
    out = np.zeros(values.shape[0])
    if scored.any():
        out[scored] = normalise(values[scored])
    return out


def provisional_priority(p: np.ndarray, alpha: float) -> float:
    """The priority of a row whose scores have not arrived: (mean_j p_j^α)^(1/α) over the given priorities p
    float[M] (> 0), so that its sampling weight p^α of eq. 20 is the mean weight of those rows: an unscored row
    is drawn as often as an average scored row, neither excluded nor favoured (DESIGN.md: "a provisional
    priority" for new transitions; A11's "score at insertion" when, as in the service, scores arrive later).
    α = 0: every row weighs 1, and 1 is returned."""
    arr = np.asarray(p, dtype=np.float64)
    if arr.size == 0:
        raise ValueError("provisional_priority needs at least one scored row, got none")
    if alpha == 0:
        return 1.0
    if arr.min() == arr.max():  # all rows alike (e.g. all at ε_p before any score): that value, exactly
        return float(arr[0])
    return float(np.mean(np.power(arr, alpha)) ** (1.0 / alpha))


def curriculum_priority(difficulty: np.ndarray, has_difficulty: np.ndarray, curiosity: np.ndarray,
                        has_curiosity: np.ndarray, lam: float, eta: float, *, eps: float = EPS_P,
                        difficulty_norm: str = "rank", cp_input: str = "std", lam_max: float = LAM_MAX,
                        reversed_difficulty: bool = False, alpha: float = 1.0) -> tuple[np.ndarray, ...]:
    """One ACL / CMCL agent's sampling priority over the M valid rows from its raw score columns.

    ĉ = normalised c over the rows that have one (§3.3, A1: rank by default); ρ̂ = normalised ρ likewise (§3.5, only
    when η > 0); p = CI(KP(ĉ, λ), CP(ρ̂), η) + ε_p (eqs. 12, 19, 8). A row without a difficulty score yet gets
    `provisional_priority` of the scored rows under the sampling exponent `alpha` (eq. 20's α_s): the sampling
    weight of an average scored row (A11; ε_p if no row is scored, i.e. uniform). The inline loop scores every new
    row before it samples, so only the service, whose teachers score asynchronously, samples such rows.
    difficulty, curiosity float[M]; has_* bool[M]; eta = 0 gives ACL. reversed_difficulty: the anti-curriculum
    control, ĉ -> 1 − ĉ on the scored rows before KP (the returned c_hat is the reversed one, the ĉ KP saw).
    Returns float64[M] arrays (c_hat, kp, cp, p) and has_difficulty.
    """
    m = difficulty.shape[0]
    c_hat = _over_scored(difficulty, has_difficulty, lambda x: normalise_difficulty(x, difficulty_norm))
    if reversed_difficulty:
        c_hat = np.where(has_difficulty, 1.0 - c_hat, 0.0)
    kp = kfold_priority(c_hat, lam, lam_max)
    cp = np.zeros(m)
    if eta > 0:
        rho_hat = _over_scored(curiosity, has_curiosity, lambda x: normalise_curiosity(x, cp_input))
        cp = curiosity_priority(rho_hat)
    p = curriculum_index(kp, cp, eta) + eps
    if not has_difficulty.all():
        p = np.where(has_difficulty, p, provisional_priority(p[has_difficulty], alpha) if has_difficulty.any() else eps)
    return c_hat, kp, cp, p, has_difficulty


def permute_priorities(p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The permuted control: each column of p float[M, A] shuffled across its M rows by an independent
    permutation from `rng` -> float64[M, A]. Every column keeps its multiset of values, so P of eq. 20 has the same
    multiset of probabilities and the same effective sample size, but which row gets which priority carries no
    information about the row. One vectorised call (`Generator.permuted`), no Python loop over rows.
    """
    return rng.permuted(np.asarray(p, dtype=np.float64), axis=0)
