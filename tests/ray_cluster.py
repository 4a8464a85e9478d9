"""A Ray cluster on 127.0.0.1 for the tests, in a process of its own: `python tests/ray_cluster.py WORKER_NODES`.

Ray's `cluster_utils.Cluster` keeps process-wide state, so two of them in the test process (or one
beside a test that is itself a Ray driver) disturb each other; here each cluster has its own process.
It prints `address HOST:PORT`, then obeys one command per line on stdin: `remove` kills the
last worker node's processes at once (a lost machine) and answers `removed`; end of input stops all.
"""

from __future__ import annotations

import sys

from ray.cluster_utils import Cluster


def main(worker_nodes: int) -> None:
    # One CPU per node: the driver holds none, so each of N workers lands on a node of its own.
    cluster = Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "node_ip_address": "127.0.0.1", "include_dashboard": False}
    )
    try:
        nodes = [cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1") for _ in range(worker_nodes)]
        print(f"address {cluster.address}", flush=True)
        for line in sys.stdin:
            if line.strip() == "remove":
                cluster.remove_node(nodes.pop(), allow_graceful=False)
                print("removed", flush=True)
    finally:
        cluster.shutdown()


if __name__ == "__main__":
    main(int(sys.argv[1]))
