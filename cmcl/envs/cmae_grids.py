"""CMAE's two sparse coordination grids, Push-Box and Pass, as PettingZoo ParallelEnvs with Discrete(5) actions.

Sources (Liu et al., "Cooperative Exploration for Multi-Agent Deep Reinforcement Learning", ICML 2021):
IouJenLiu/CMAE env/push_box.py (`PushBox`) and env/rooms.py (`Rooms`), at the settings of env/env_factory.py
(`push_box`: H=300, grid_size=15; `room30`, the Pass task: H=300, grid_size=30), both with 2 agents.

* Push-Box (`push_box_env`): a 15 x 15 grid; agents start at (11, 11) and (9, 9); a 3 x 3 box centred at (7, 7)
  that agents cannot enter. The box moves one cell in a direction only when at least 2 agents stand adjacent to it on
  the same side (within its span) and both push that way in the same step; it moves first, then the agents. Success
  (reward 1 to every agent, the episode terminates): the box touches the border.
* Pass (`pass_env`): a 30 x 30 grid with a wall at column x = 15; agents start at (4, 4) and (3, 3). The door, the
  wall's cells (15, 12)..(15, 18) around (15, 15), is open while some agent is within 4.5 (Euclidean) of a switch at
  (3, 24) or (24, 3), re-evaluated after the agents move (so it is the previous step's state an agent walks into).
  Success (reward 1, termination): both agents at x >= 16.

Both: 300 steps (then truncation); reward 1 on success else 0 (the sources' sparse setting, no checkpoint rewards);
actions 0 stay, 1 up (y - 1), 2 down (y + 1), 3 left (x - 1), 4 right (x + 1) -- the sources have the four moves
only, the stay is the issue's; a move into the border, a wall or the box leaves the agent where it is; agents do not
block each other. Agents act one after another in index order, as in the sources. Observation of each agent,
float32 in [0, 1]: its own (x, y), the other agent's (x, y), then the box centre (Push-Box) or the door bit (Pass);
coordinates divided by grid_size - 1 (the sources observe the same state as integers). Positions are (x, y) with
x the column and y the row. The initial state is fixed (the sources have no random start), so `reset(seed)` only
re-seeds nothing.

Per step every agent's info: success (the task solved in this step); the runners read its last value
(env.success_key = "success"; presets configs/push_box_maddpg.toml, configs/pass_maddpg.toml).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

STAY, UP, DOWN, LEFT, RIGHT = range(5)
MOVES = {STAY: (0, 0), UP: (0, -1), DOWN: (0, 1), LEFT: (-1, 0), RIGHT: (1, 0)}


class _GridEnv(ParallelEnv):
    """Two agents on a grid; subclasses define `_start`, `_blocked`, `_advance` (box / door) and `_solved`."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "is_parallelizable": True}
    extra_obs = 0
    SETTINGS: tuple[str, ...] = ()  # the attributes `set_setting` may change (cmcl.envs.world_settings)

    def __init__(self, grid_size: int, max_cycles: int = 300, render_mode: str | None = None) -> None:
        self.grid_size, self.max_cycles, self.render_mode = int(grid_size), int(max_cycles), render_mode
        self.possible_agents = ["agent_0", "agent_1"]
        self.agents: list[str] = []
        self._obs_space = spaces.Box(0.0, 1.0, (4 + self.extra_obs,), np.float32)
        self._act_space = spaces.Discrete(5)
        self.pos = np.zeros((2, 2), np.int64)  # [agent, (x, y)]
        self.steps = 0
        self.settings: dict[str, float] = {}  # world settings the next reset applies (`set_setting`)

    def observation_space(self, agent: str) -> spaces.Space:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space:
        return self._act_space

    def set_setting(self, name: str, value: float) -> None:
        """World setting `name` (cmcl.envs.world_settings: Push-Box's push_cells, Pass's switch_reach) = `value`
        from the next reset on."""
        if name not in self.SETTINGS:
            raise ValueError(f"world setting {name!r}: this grid's are {list(self.SETTINGS)}")
        self.settings[name] = float(value)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        for name, value in ((options or {}).get("settings") or {}).items():
            self.set_setting(name, value)
        for name, value in self.settings.items():
            setattr(self, name, type(getattr(self, name))(value))
        self.pos = self._start()
        self.steps = 0
        self.agents = list(self.possible_agents)
        return self._observe(), {a: {} for a in self.agents}

    def _observe(self) -> dict[str, np.ndarray]:
        scale = 1.0 / (self.grid_size - 1)
        extra = self._extra()
        return {a: np.concatenate([self.pos[i] * scale, self.pos[1 - i] * scale, extra]).astype(np.float32)
                for i, a in enumerate(self.possible_agents)}

    def _move(self, i: int, action: int) -> None:
        dx, dy = MOVES[action]
        x, y = self.pos[i, 0] + dx, self.pos[i, 1] + dy
        if (dx or dy) and 0 <= x < self.grid_size and 0 <= y < self.grid_size and not self._blocked(x, y):
            self.pos[i] = (x, y)

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("step() called with no live agents: the episode has ended, call reset()")
        acts = []
        for a in self.possible_agents:
            act = int(np.asarray(actions[a]).reshape(()))
            if act not in MOVES:
                raise ValueError(f"action of {a} must be in 0..4, got {act}")
            acts.append(act)
        self._advance(acts)
        self.steps += 1
        solved = self._solved()
        truncated = self.steps >= self.max_cycles and not solved
        reward = 1.0 if solved else 0.0
        obs = self._observe()
        rew = {a: reward for a in self.agents}
        terms = {a: solved for a in self.agents}
        truncs = {a: truncated for a in self.agents}
        infos = {a: {"success": solved} for a in self.agents}
        if solved or truncated:
            self.agents = []
        return obs, rew, terms, truncs, infos

    def render(self) -> np.ndarray | None:
        """uint8[8G, 8G, 3]: walls / box grey, agents red and blue."""
        g = self.grid_size
        img = np.full((g, g, 3), 255, np.uint8)
        for y in range(g):
            for x in range(g):
                if self._blocked(x, y):
                    img[y, x] = 120
        for i, colour in enumerate(((220, 40, 40), (40, 40, 220))):
            img[self.pos[i, 1], self.pos[i, 0]] = colour
        return np.kron(img, np.ones((8, 8, 1), np.uint8))

    def close(self) -> None:
        pass

    # ----- subclass hooks -----
    def _start(self) -> np.ndarray:
        raise NotImplementedError

    def _extra(self) -> np.ndarray:
        raise NotImplementedError

    def _blocked(self, x: int, y: int) -> bool:
        raise NotImplementedError

    def _advance(self, acts: list[int]) -> None:
        raise NotImplementedError

    def _solved(self) -> bool:
        raise NotImplementedError


class PushBoxEnv(_GridEnv):
    """CMAE's Push-Box (IouJenLiu/CMAE env/push_box.py); module docstring."""

    metadata = {**_GridEnv.metadata, "name": "push_box_v0"}
    extra_obs = 2
    BOX_RADIUS = 1  # a 3 x 3 box
    SETTINGS = ("push_cells",)

    def __init__(self, grid_size: int = 15, max_cycles: int = 300, render_mode: str | None = None) -> None:
        super().__init__(grid_size, max_cycles, render_mode)
        self.box = np.zeros(2, np.int64)
        self.box_start = np.zeros(2, np.int64)
        # cells the box must move from its start (along x or y) to solve the task; the source's: centre to border
        self.push_cells = self.grid_size // 2 - self.BOX_RADIUS

    def _start(self) -> np.ndarray:
        half = self.grid_size // 2
        self.box = np.array([half, half])
        self.box_start = self.box.copy()
        return np.array([[4 + half, 4 + half], [2 + half, 2 + half]])

    def _extra(self) -> np.ndarray:
        return self.box / (self.grid_size - 1)

    def _blocked(self, x: int, y: int) -> bool:
        r = self.BOX_RADIUS
        return abs(x - self.box[0]) <= r and abs(y - self.box[1]) <= r

    def pushes(self, acts: list[int]) -> dict[int, int]:
        """Direction -> agents standing next to the box on the side opposite to it and moving that way."""
        r, (bx, by) = self.BOX_RADIUS, self.box
        force = {UP: 0, DOWN: 0, LEFT: 0, RIGHT: 0}
        for (x, y), act in zip(self.pos, acts, strict=True):
            if by - r <= y <= by + r:
                if x == bx + r + 1 and act == LEFT:
                    force[LEFT] += 1
                elif x == bx - r - 1 and act == RIGHT:
                    force[RIGHT] += 1
            if bx - r <= x <= bx + r:
                if y == by - r - 1 and act == DOWN:
                    force[DOWN] += 1
                elif y == by + r + 1 and act == UP:
                    force[UP] += 1
        return force

    def _advance(self, acts: list[int]) -> None:
        r, g = self.BOX_RADIUS, self.grid_size
        for direction, count in self.pushes(acts).items():
            if count >= 2:
                dx, dy = MOVES[direction]
                x, y = self.box[0] + dx, self.box[1] + dy
                if r <= x <= g - 1 - r and r <= y <= g - 1 - r:
                    self.box = np.array([x, y])
                break
        for i, act in enumerate(acts):
            self._move(i, act)

    def _solved(self) -> bool:
        r, g, (x, y) = self.BOX_RADIUS, self.grid_size, self.box
        moved = int(np.abs(self.box - self.box_start).max()) >= self.push_cells
        return moved or x - r == 0 or x + r == g - 1 or y - r == 0 or y + r == g - 1


class PassEnv(_GridEnv):
    """CMAE's Pass, the `room30` Rooms task (IouJenLiu/CMAE env/rooms.py); module docstring."""

    metadata = {**_GridEnv.metadata, "name": "pass_v0"}
    extra_obs = 1
    SETTINGS = ("switch_reach",)

    def __init__(self, grid_size: int = 30, max_cycles: int = 300, render_mode: str | None = None) -> None:
        super().__init__(grid_size, max_cycles, render_mode)
        g = self.grid_size
        self.wall_x = g // 2
        self.door_y = g // 2
        self.door_radius = g // 10
        self.switches = np.array([[g // 10, int(g * 0.8)], [int(g * 0.8), g // 10]])
        self.switch_reach = 1.5 * self.door_radius
        self.door_open = False

    def _start(self) -> np.ndarray:
        self.door_open = False
        k = self.grid_size // 10
        return np.array([[1 + k, 1 + k], [k, k]])

    def _extra(self) -> np.ndarray:
        return np.array([float(self.door_open)])

    def _blocked(self, x: int, y: int) -> bool:
        if x != self.wall_x:
            return False
        return not (self.door_open and abs(y - self.door_y) <= self.door_radius)

    def switch_pressed(self) -> bool:
        """Some agent within switch_reach of some switch."""
        d = np.sqrt(np.square(self.pos[:, None, :] - self.switches[None]).sum(-1))
        return bool((d <= self.switch_reach).any())

    def _advance(self, acts: list[int]) -> None:
        for i, act in enumerate(acts):
            self._move(i, act)
        self.door_open = self.switch_pressed()

    def _solved(self) -> bool:
        return bool((self.pos[:, 0] >= self.grid_size / 2 + 1).all())


def push_box_env(**kwargs: Any) -> PushBoxEnv:
    """CMAE's Push-Box (grid_size=15, max_cycles=300, render_mode=None)."""
    return PushBoxEnv(**kwargs)


def pass_env(**kwargs: Any) -> PassEnv:
    """CMAE's Pass (grid_size=30, max_cycles=300, render_mode=None)."""
    return PassEnv(**kwargs)
