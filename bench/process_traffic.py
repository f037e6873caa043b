"""Bytes between cooperating processes: a sweep of many short-lived learners run as N
processes on localhost, with every TCP connection to the coordinator's port read from the
kernel (``ss -tin``: bytes sent and received per connection) while the processes run.

The kernel's counters see everything that crosses the coordinator's socket (the key-value
store, JAX's own heartbeats and barriers), whatever code sends it, so the same script
measures any version of mjxcpg: run it from another checkout's root with ``--code DIR``.

    .venv/bin/python bench/process_traffic.py --learners 1024 --processes 4 --out /tmp/traffic
    .venv/bin/python bench/process_traffic.py ... --code /tmp/old-checkout

The set-up: every learner has one trial of ``--trial-seconds`` (so all are done after the
same number of chunks, ``trial_seconds / chunk_seconds``, unless a robot falls first) and
no success criterion to wait for.  Prints a JSON line: total bytes over every connection
(each counted once, at the client's end), the one-process chunk count, bytes per chunk and
per learner per chunk.
"""

from __future__ import annotations

import argparse
import json
import re
import socket
import subprocess
import sys
import time
from pathlib import Path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def client_bytes(port: int) -> dict[str, int]:
    """Per client connection to ``port`` (keyed by its local address): bytes sent + received."""
    text = subprocess.run(["ss", "-tinH", "state", "established", f"( dport = :{port} )"],
                          capture_output=True, text=True, check=True).stdout
    found, key = {}, None
    for line in text.splitlines():
        if not line.startswith((" ", "\t")):
            parts = line.split()
            key = parts[2] if len(parts) >= 4 else None  # Recv-Q Send-Q Local Peer
            continue
        if key is None:
            continue
        sent = re.search(r"bytes_sent:(\d+)", line)
        received = re.search(r"bytes_received:(\d+)", line)
        found[key] = (int(sent.group(1)) if sent else 0) + (int(received.group(1)) if received else 0)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", type=int, default=1024)
    parser.add_argument("--processes", type=int, default=4)
    parser.add_argument("--trial-seconds", type=float, default=1.0)
    parser.add_argument("--chunk-seconds", type=float, default=0.5)
    parser.add_argument("--engine", default="native")
    parser.add_argument("--code", type=Path, default=Path(__file__).resolve().parent.parent,
                        help="the checkout whose mjxcpg runs (its root; default: this one)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()

    args.out.mkdir(parents=True, exist_ok=True)
    spec = {"k_s": [10.0] * args.learners, "seeds": list(range(args.learners)),
            "chunk_seconds": args.chunk_seconds,
            "trial": {"max_trials": 1, "trial_seconds": args.trial_seconds,
                      "hand_seconds": [args.trial_seconds / 4, args.trial_seconds / 2], "success_streak": 1}}
    config = args.out / "traffic.json"
    config.write_text(json.dumps(spec))
    port = free_port()
    run = args.out / "run"
    command = [sys.executable, "-m", "mjxcpg", "sweep", "--config", str(config), "--out", str(run), "--force",
               "--quiet", "--no-tensorboard", "--engine", args.engine,
               "--coordinator", f"localhost:{port}", "--num-processes", str(args.processes)]
    start = time.perf_counter()
    procs = [subprocess.Popen(command + ["--process-id", str(i)], cwd=args.code, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True) for i in range(args.processes)]
    seen: dict[str, int] = {}
    while any(p.poll() is None for p in procs):
        for connection, count in client_bytes(port).items():
            seen[connection] = max(seen.get(connection, 0), count)
        time.sleep(0.2)
    errors = [p.stderr.read() for p in procs]
    if any(p.returncode for p in procs):
        sys.exit("a process failed:\n" + "\n".join(errors))
    chunks = round(args.trial_seconds / args.chunk_seconds)
    total = sum(seen.values())
    print(json.dumps({"learners": args.learners, "processes": args.processes, "engine": args.engine,
                      "code": str(args.code), "connections": len(seen), "bytes": total, "chunks": chunks,
                      "bytes_per_chunk": total / chunks, "bytes_per_learner_per_chunk": total / chunks / args.learners,
                      "wall_s": round(time.perf_counter() - start, 1)}))


if __name__ == "__main__":
    main()
