"""A minimal robot-side controller for shelfpick's robot protocol (docs/robot-protocol.md).

Plain sockets and JSON, one connection at a time, no shelfpick import: the shape a robot team
ports to its own language and motion stack. Replace `move_and_pull` with the robot's motion.

    python examples/robot_controller.py --port 9000 [--step-time 2]
    shelfpick console --robot tcp://127.0.0.1:9000

What it does per connection: answer `hello`; for each `step`, refuse a (run, plan, step) it
already did (DUPLICATE_STEP), `ack` it, move (answering `ping` and watching for `abort` while
moving), then `done`, or `aborted` when told to stop; stop moving when the link drops.
"""
from __future__ import annotations

import argparse
import json
import select
import socket
import sys
import time

PROTOCOL = "shelfpick.robot/1"
MAX_LINE = 1 << 20


class Link:
    """Line-delimited JSON over one TCP connection."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.buf = b""

    def send(self, msg: dict) -> None:
        self.sock.sendall(json.dumps(msg).encode() + b"\n")

    def recv(self, timeout: float | None) -> dict | None:
        """The next message, None when none came within `timeout`; EOFError when the link is gone."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while b"\n" not in self.buf:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([self.sock], [], [], left)
            if not ready:
                return None
            chunk = self.sock.recv(65536)
            if not chunk or len(self.buf) > MAX_LINE:
                raise EOFError
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return json.loads(line) if line.strip() else self.recv(timeout)


def move_and_pull(link: Link, step: dict, step_time: float) -> bool:
    """The robot's motion for one step: here a wait. Answers pings meanwhile; False when aborted."""
    grasp = step["grasp"]
    print(f"step {step['step']}: suction at {grasp['point']}, pull {step['pull_distance']:.3f} m "
          f"along {[-c for c in grasp['approach']]}", flush=True)
    end = time.monotonic() + step_time
    while time.monotonic() < end:
        msg = link.recv(min(0.05, max(0.0, end - time.monotonic())))
        if msg is None:
            continue
        if msg.get("type") == "ping":
            link.send({"type": "pong", "seq": msg.get("seq")})
        elif msg.get("type") == "abort":
            return False
    return True


def serve_connection(link: Link, done_steps: set, step_time: float) -> None:
    hello = link.recv(10.0)
    if not hello or hello.get("type") != "hello" or hello.get("protocol") != PROTOCOL:
        link.send({"type": "error", "plan": None, "step": None, "code": "BAD_REQUEST", "message": "hello expected"})
        return
    link.send({"type": "hello", "protocol": PROTOCOL, "robot": "example-controller"})
    run, plan = hello.get("run"), hello.get("plan")
    while True:
        msg = link.recv(None)
        kind = msg.get("type")
        if kind == "ping":
            link.send({"type": "pong", "seq": msg.get("seq")})
        elif kind == "abort":
            link.send({"type": "aborted", "plan": plan, "step": msg.get("step"), "completed": False})
            return
        elif kind == "bye":
            return
        elif kind == "step":
            i, box = msg.get("step"), msg.get("box")
            key = (run, plan, i)
            if msg.get("run") != run or msg.get("plan") != plan or not isinstance(i, int):
                link.send({"type": "error", "plan": plan, "step": i, "code": "BAD_REQUEST",
                           "message": "step of another run or plan"})
            elif key in done_steps:
                link.send({"type": "error", "plan": plan, "step": i, "code": "DUPLICATE_STEP",
                           "message": "this step of this run was already executed"})
            else:
                link.send({"type": "ack", "plan": plan, "step": i, "box": box})   # may move from now on
                done_steps.add(key)
                if move_and_pull(link, msg, step_time):
                    link.send({"type": "done", "plan": plan, "step": i, "box": box, "detail": {}})
                else:
                    link.send({"type": "aborted", "plan": plan, "step": i, "completed": False})
                    return
        else:
            link.send({"type": "error", "plan": plan, "step": msg.get("step"), "code": "BAD_REQUEST",
                       "message": f"unknown type {kind!r}"})


def main() -> int:
    p = argparse.ArgumentParser(description="a minimal shelfpick robot-side controller (plain sockets)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=9000, help="port (0: any free one; default 9000)")
    p.add_argument("--step-time", type=float, default=1.0, help="seconds one pull takes (default 1)")
    args = p.parse_args()
    server = socket.create_server((args.host, args.port))
    print(f"listening on {args.host}:{server.getsockname()[1]}", flush=True)
    done_steps: set = set()     # (run, plan, step): never repeat a step of one run, across connections
    while True:
        conn, peer = server.accept()
        with conn:
            try:
                serve_connection(Link(conn), done_steps, args.step_time)
            except (EOFError, OSError, ValueError) as exc:   # link lost or garbage: stop moving, wait again
                print(f"{peer}: connection ended ({type(exc).__name__})", flush=True)


if __name__ == "__main__":
    sys.exit(main())
