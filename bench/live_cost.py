"""What `LIVE=1` costs the simulation: µs per step without the live view, with it and nobody watching, and with a
client subscribed to every topic.

    .venv/bin/python -m bench.live_cost            # the table in docs/benchmarks.md, "Live view"

The three are measured in turns (ABCABC...) on the same expert episodes, so that a shared machine's
drift falls on all of them alike; the table gives medians. The client is another process (this
module with --watch), as the Foxglove app would be.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

from websockets.sync.client import connect

from humanoid.env import make_env
from rollout.controllers import make_controller
from rollout.episode import EpisodeBuffer, run_episode
from teleop.live import LivePublisher

SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]


def watch(port: int) -> None:
    """Be the client: subscribe to every advertised channel, count messages until the server closes; print the count."""
    messages = 0
    with connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS) as client:
        json.loads(client.recv(timeout=10))  # serverInfo
        channels: list[dict] = []
        while len(channels) < 4:
            channels += json.loads(client.recv(timeout=10)).get("channels", [])
        subscriptions = [{"id": i, "channelId": channel["id"]} for i, channel in enumerate(channels)]
        client.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        print("subscribed", flush=True)
        try:
            for _ in client:
                messages += 1
        except Exception:  # the server stopped: the benchmark is over
            pass
    print(messages, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=5, help="turns of each case (an episode of 1000 steps each)")
    parser.add_argument("--watch", type=int, default=None, help=argparse.SUPPRESS)  # the client process's role
    args = parser.parse_args()
    if args.watch is not None:
        watch(args.watch)
        return
    env = make_env()
    expert = make_controller("expert", env)
    buffer = EpisodeBuffer(env, env.spec.max_episode_steps)
    idle = LivePublisher(env, port=0)
    watched = LivePublisher(env, port=0)
    # The client is another process, as the Foxglove app would be: in this one it would compete for the GIL.
    command = [sys.executable, "-m", "bench.live_cost", "--watch", str(watched.port)]
    watcher = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    assert watcher.stdout.readline().strip() == "subscribed"
    time.sleep(0.5)  # the subscription reaches the server
    cases = {"no live view": None, "live view, no client": idle, "live view, a client on every topic": watched}
    micros: dict[str, list[float]] = {name: [] for name in cases}
    for round_index in range(args.rounds):
        for name, observer in cases.items():
            start = time.perf_counter()
            episode = run_episode(env, expert, 5000 + round_index, buffer=buffer, observer=observer)
            micros[name].append((time.perf_counter() - start) / episode.length * 1e6)
    base = statistics.median(micros["no live view"])
    print("| case | µs per step (median) | vs no live view |")
    print("|---|---|---|")
    for name, values in micros.items():
        print(f"| {name} | {statistics.median(values):.0f} | {statistics.median(values) / base:.2f}× |")
    idle.close()
    watched.close()
    received = int(watcher.stdout.readline())
    watcher.wait(timeout=30)
    print(f"\nThe client received {received:,} messages ({args.rounds} episodes x 1000 steps x 3 topics, and /scene).")


if __name__ == "__main__":
    main()
