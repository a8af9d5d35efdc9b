# Two set-up commands for a fresh machine: `make run` and `make test` (see README.md).
# Both create .venv if missing and install the project; torch is pinned to the CPU wheel first
# (an unpinned torch would pull a multi-GB CUDA build).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
TORCH  := torch==2.13.0
RUN_ARGS ?=
RUN_DIR ?= runs/make-run
RUN_EPISODES ?= 60000
RESUME_EPISODES ?= 60000
TEST_ARGS ?=

# Appended to a training command: its exit status after a graceful stop (130 Ctrl-C, 143 SIGTERM) is not an error.
STOPPED_IS_OK := || { status=$$?; [ $$status -eq 130 ] || [ $$status -eq 143 ] || exit $$status; }

.PHONY: install system-deps run resume demo test test-lab test-extended test-deploy lint bench peer peer-benchmarl clean

$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet $(TORCH)
	$(BIN)/python -m pip install --quiet -e '.[dev,envs]'
	touch $(STAMP)

install: $(STAMP)

# The main job: MADDPG with uniform replay on the distributed service (embedded Ray) trains sparse navigation until the
# 100-episode moving average of coverage reaches 0.9, or 5 minutes (or RUN_EPISODES episodes, set above what 5
# minutes hold on a fast machine, so that the minutes are the budget); then a held-out evaluation, a GIF and the
# learning curve. Uniform replay until a sampling rule beats it (docs/RESULTS.md); the paper's CMCL is one flag away:
# `make run RUN_ARGS="--set teams.agent.algorithm=cmcl"`.
# Ctrl-C (or SIGTERM) stops it with every role checkpointed and the resume command printed; the run's exit 130 / 143
# is not reported as an error of make's (on Ctrl-C make, which got the SIGINT too, only says "Interrupt").
# `make resume` goes on from there, for 5 more minutes or RESUME_EPISODES more episodes (a run that ended at its
# episode budget unsolved trains further too; λ keeps its schedule; one that reached MA 0.9 stops again once 100 new
# episodes show it: RUN_ARGS="--set run.stop_coverage=0" trains it on).
run: install
	$(BIN)/python -m cmcl train --runner service --config configs/spread_maddpg.toml --set run.dir=$(RUN_DIR) \
		--set run.stop_coverage=0.9 --set run.max_seconds=300 --set run.episodes=$(RUN_EPISODES) --overwrite \
		$(RUN_ARGS) $(STOPPED_IS_OK)

resume: install
	$(BIN)/python -m cmcl resume $(RUN_DIR) --more-episodes $(RESUME_EPISODES) $(RUN_ARGS) $(STOPPED_IS_OK)

demo: install
	$(BIN)/python -m cmcl.run.demo

# The live-dashboard tests need a real Prometheus and a real Chromium (Debian packages). As root with apt-get they
# are installed when missing; elsewhere a note is printed and those tests skip, saying why.
system-deps:
	@if command -v prometheus >/dev/null && command -v chromium >/dev/null; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq prometheus chromium >/dev/null; \
	else echo "note: prometheus / chromium missing and not installable here (not root or no apt-get):" \
		"tests/test_live_dashboard.py will skip"; fi

# The product and the grid runner: tests/ (pyproject's testpaths); nothing of lab/ is imported.
test: install system-deps
	$(BIN)/python -m pytest -n 2 --dist loadfile $(TEST_ARGS)

# The research record: the report, the doc-generation code and the pages' generated blocks (lab/tests/).
test-lab: install
	$(BIN)/python -m pytest -n 2 --dist loadfile lab/tests $(TEST_ARGS)

# The cases kept out of `make test` for its 10-minute budget (marker `extended`: more runners, faults and
# environments of paths the default run covers once). The hours-long learning runs stay under `-m slow`.
test-extended: install system-deps
	$(BIN)/python -m pytest -m extended $(TEST_ARGS)

# docker-compose.yml run for real with podman (tests/test_compose_live.py, marker `deploy`): base images from the
# Debian mirror, the wheelhouse, the images, then the stack up, checked and down. Podman settings: deploy/README.md.
DEPLOY_PKGS := podman podman-compose runc mmdebstrap prometheus chromium
test-deploy: export CONTAINERS_CONF := $(CURDIR)/deploy/podman/containers.conf
test-deploy: export CMCL_BASE_IMAGE := localhost/cmcl-python:3.11
test-deploy: export CMCL_DEBIAN_IMAGE := localhost/cmcl-debian:bookworm
test-deploy: export TIMEFORMAT := %0R s
test-deploy: SHELL := /bin/bash
test-deploy: install
	@missing=$$(for p in $(DEPLOY_PKGS); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; fi
	time nice -n 10 deploy/build_base.sh
	time PYTHON=$(BIN)/python nice -n 10 deploy/wheelhouse.sh
	time CMCL_RAY_TOKEN=unused-at-build nice -n 10 podman-compose build cmcl-head prometheus >/dev/null
	podman image prune -f --filter label=io.cmcl.project=cmcl-service >/dev/null  # superseded builds
	podman image ls --format '{{.Repository}}:{{.Tag}} {{.Size}}'; du -sh $$(podman info --format '{{.Store.GraphRoot}}') deploy/wheels
	time CMCL_DEPLOY_STRICT=1 $(BIN)/python -m pytest -m deploy -rs -s tests/test_compose_live.py $(TEST_ARGS)

lint: install
	$(BIN)/ruff check .

# Benchmarks print ratios against a peer run in the same process. VMAS (the vectorised peer of the env bench)
# installs without its dependencies so that it cannot replace the pinned CPU torch.
bench: install
	$(BIN)/python -m pip install --quiet --no-deps vmas gym gym-notices
	$(BIN)/python bench/env_throughput.py
	$(BIN)/python bench/learner_throughput.py
	$(BIN)/python bench/replay_throughput.py

# The peer of the time-to-solve table: AgileRL's MADDPG in its own venv (never a dependency of this package;
# --no-deps because agilerl pins pettingzoo<1.27 and would pull another torch). See bench/peer_agilerl.py.
PEER := .venv-peer
peer:
	test -x $(PEER)/bin/python || $(PYTHON) -m venv $(PEER)
	$(PEER)/bin/python -m pip install --quiet $(TORCH)
	$(PEER)/bin/python -m pip install --quiet -e .
	$(PEER)/bin/python -m pip install --quiet --no-deps agilerl==2.58.0 "agilerl-arena>=1.28,<2" tensordict==0.13.0 \
		accelerate peft transformers wandb dill fastrand xxhash regex
	$(PEER)/bin/python -m pip install --quiet lazy-loader importlib_metadata orjson pyvers huggingface_hub \
		safetensors tokenizers typer
	OMP_NUM_THREADS=1 $(PEER)/bin/python bench/peer_agilerl.py --seed 0 --out lab/results/peer_agilerl/agilerl_seed0.json

# The BenchMARL peer (issue 39): BenchMARL 1.5.2 MAPPO / MADDPG on our sparse navigation through TorchRL's
# PettingZooWrapper, in its own venv; --no-deps throughout (benchmarl -> torchrl -> torch would replace the CPU
# torch). torchvision (a declared BenchMARL dependency, never imported by BenchMARL's code) is left out: PyPI's
# torchvision 0.28.0 wheel links libtorch_cuda.so and fails to import next to the CPU torch ("operator
# torchvision::nms does not exist"). See bench/peer_benchmarl.py and docs/PERFORMANCE.md "BenchMARL peer (set-up)".
BENCHMARL_VENV := .venv-benchmarl
PEER_ALGORITHM ?= mappo
PEER_SECONDS ?= 300
PEER_SEED ?= 0
PEER_ARGS ?=
peer-benchmarl:
	test -x $(BENCHMARL_VENV)/bin/python || $(PYTHON) -m venv $(BENCHMARL_VENV)
	$(BENCHMARL_VENV)/bin/python -m pip install --quiet $(TORCH)
	$(BENCHMARL_VENV)/bin/python -m pip install --quiet -e .
	$(BENCHMARL_VENV)/bin/python -m pip install --quiet --no-deps benchmarl==1.5.2 torchrl==0.11.1 tensordict==0.11.0
	$(BENCHMARL_VENV)/bin/python -m pip install --quiet cloudpickle packaging importlib_metadata orjson \
		"pyvers>=0.2,<0.3" tqdm hydra-core "av<14"
	OMP_NUM_THREADS=1 nice -n 10 $(BENCHMARL_VENV)/bin/python bench/peer_benchmarl.py --algorithm $(PEER_ALGORITHM) \
		--seconds $(PEER_SECONDS) --seed $(PEER_SEED) \
		--out lab/results/peer_benchmarl/$(PEER_ALGORITHM)_seed$(PEER_SEED).json $(PEER_ARGS)

clean:
	rm -rf $(VENV) .pytest_cache
