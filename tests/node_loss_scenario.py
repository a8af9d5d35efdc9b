"""The loss of a worker node, on a real 2-node `ray.cluster_utils.Cluster` with fast health checks. Run as its own
process (a driver joins one Ray cluster only, and the test session already has its embedded one):

    python -m tests.node_loss_scenario RUN_DIR     # prints one JSON line: what happened

The head node (1 CPU) holds the replay server and the learner; the rollout worker needs the custom resource
`rollout_node` (`service.rollout_resource`), which only the worker node has. Once the worker has reported, the
worker node is removed without grace (its raylet and the worker's process are killed), and a replacement node
joins, as an autoscaler would bring one. Ray's health checks declare the lost node dead, the rollout worker
restarts on the new node, and training goes on to its exact episode target.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import ray
from ray.cluster_utils import Cluster

from cmcl.run.rundir import RunDirectory
from services.observability.metrics import ServiceMetrics
from services.runtime.placement import create_roles
from services.runtime.supervisor import Supervisor
from tests.faults import actor_entry
from tests.test_service_ray import samples, value
from tests.tiny import make_tiny_config

FAST_HEALTH = {"health_check_initial_delay_ms": 0, "health_check_period_ms": 500, "health_check_timeout_ms": 500,
               "health_check_failure_threshold": 2}
EPISODES = 80


def main(run_path: str) -> dict:
    """Train with a node lost on the way; returns the summary, the counters and where the worker ran."""
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False,
                                                            "_system_config": FAST_HEALTH})
    worker_node = cluster.add_node(num_cpus=1, resources={"rollout_node": 1})
    ray.init(address=cluster.address, log_to_driver=False)
    try:
        # the rollout worker runs only where the custom resource is: on the worker node
        config = make_tiny_config("maddpg", service=True, sections={"service": {"rollout_resource": "rollout_node"}},
                                  dir=str(Path(run_path)), episodes=EPISODES)
        run_dir = RunDirectory.create(config.run.dir, config)
        metrics = ServiceMetrics()
        roles = create_roles(config, run_dir)
        supervisor = Supervisor(config, run_dir, roles, metrics, progress=None)
        apply, lost = supervisor._apply, {}

        def apply_then_lose_the_node(kind, index, value_, *number):
            apply(kind, index, value_, *number)
            if kind == "rollout_report" and not lost:
                lost.update(node_before=actor_entry(roles.rollout[0])["Address"]["NodeID"],
                            incarnation_before=value_.incarnation, lost_at=time.monotonic())
                cluster.remove_node(worker_node, allow_graceful=False)
                lost["node_after_expected"] = cluster.add_node(num_cpus=1, resources={"rollout_node": 1}).node_id
            elif kind == "rollout_report" and value_.incarnation != lost["incarnation_before"] \
                    and "recovered_after_s" not in lost:  # the first report of the restarted worker
                lost["recovered_after_s"] = time.monotonic() - lost.pop("lost_at")

        supervisor._apply = apply_then_lose_the_node
        summary = supervisor.run()
        parsed = samples(metrics.text())
        entry = actor_entry(roles.rollout[0])
        return {"episodes": summary["episodes"], "env_steps": summary["env_steps"],
                "episode_length": config.env.episode_length, "target": EPISODES,
                "inserts": value(parsed, "cmcl_replay_inserts_total"),
                "restarts": value(parsed, "cmcl_actor_restarts_total", role="rollout"),
                "failures": summary["failures"], "recovery_s": summary["recovery_s"],
                "num_restarts": entry["NumRestarts"], "node_now": entry["Address"]["NodeID"],
                "dead_nodes": sum(not n["Alive"] for n in ray.nodes()), **lost}
    finally:
        ray.shutdown()
        cluster.shutdown()


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1])), flush=True)
