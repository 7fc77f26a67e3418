#!/usr/bin/env python3
"""Reads a running softarm stack from Python over iceoryx2: its ``setpoint``, ``stats`` and
``status`` services.

    python3 read_live.py --namespace softarm/sim [--seconds 5] [--json] [--every-setpoint]
                         [--set-id ID] [--stats N]

Text output: a line per second summing up the setpoints (how many, the rate, the controller's
state, the last actuation), one line per finished execution (``ExecutionStats``: the error at
each conditioning point in mm, mean and max), and a summary at the end. ``--every-setpoint``
prints every setpoint instead (500 a second with the default config).

``--json`` prints one JSON object per line instead: ``{"kind": "stats", ...}`` per execution and,
last, ``{"kind": "summary", "setpoints": N, "missed": M, "states": {"IDLE": n, ...},
"last_state": "EXECUTE", "last_actuation": [...], "status": {...} | null,
"stats": [{"set_id": .., "execution": .., "executions": .., "count": .., "errors_mm": [..],
"mean_mm": .., "max_mm": .., "reconditions": ..}, ...]}``.

It stops after ``--seconds`` (default 5), or sooner once ``--stats N`` executions' stats (of
set ``--set-id`` if given) arrived. Late subscribers get the last 64 executions' stats first.
Exit code 0 when setpoints arrived, 1 when none did (is the stack running in that namespace?).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import Counter

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import softarm_ipc as sa  # noqa: E402


def stats_dict(s: sa.ExecutionStats) -> dict:
    """An execution's stats as ``softarm stats --json`` prints each (mm)."""
    return {
        "set_id": s.set_id,
        "execution": s.execution,
        "executions": s.executions,
        "count": s.count,
        "errors_mm": [round(e * 1e3, 3) for e in s.errors()],
        "mean_mm": round(s.mean_m * 1e3, 3),
        "max_mm": round(s.max_m * 1e3, 3),
        "reconditions": s.reconditions,
        "within": [bool(s.within >> n & 1) for n in range(len(s.errors()))],
        "beyond_reach": [bool(s.beyond_reach >> n & 1) for n in range(len(s.errors()))],
    }


def status_dict(s: sa.ControllerStatus) -> dict:
    return {
        "state": sa.ControllerState.name_of(s.state),
        "set_id": s.set_id,
        "execution": s.execution,
        "rate_hz": s.rate_hz,
        "ticks": s.ticks,
        "overruns": s.overruns,
        "model_loaded": s.model_loaded == 1,
        "latency_p99_ns": s.latency.p99_ns,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--namespace", default="softarm/sim", help="the stack's namespace")
    ap.add_argument("--seconds", type=float, default=5.0, help="how long to read at most")
    ap.add_argument("--json", action="store_true", help="JSON lines")
    ap.add_argument("--every-setpoint", action="store_true", help="a line per setpoint")
    ap.add_argument("--set-id", type=int, help="only this set's stats")
    ap.add_argument("--stats", type=int, help="stop once this many executions' stats arrived")
    args = ap.parse_args()
    ns = sa.check_namespace(args.namespace)

    node = sa.open_node(ns, f"python.{os.getpid()}")
    setpoints = sa.subscribe(node, ns, "setpoint")
    stats_sub = sa.subscribe(node, ns, "stats")
    status_sub = sa.subscribe(node, ns, "status")

    count = 0
    missed = 0
    last_seq = None
    last = None
    states: Counter[str] = Counter()
    stats: list[dict] = []
    status = None
    start = time.monotonic()
    next_report = start + 1.0
    reported = (0, start)

    def out(line: str) -> None:
        print(line, flush=True)

    try:
        while time.monotonic() - start < args.seconds:
            for sp in setpoints.receive_all():
                count += 1
                if last_seq is not None and sp.seq > last_seq + 1:
                    missed += sp.seq - last_seq - 1
                last_seq = sp.seq
                last = sp
                state = sa.ControllerState.name_of(sp.state)
                states[state] += 1
                if args.every_setpoint and not args.json:
                    act = " ".join(f"{a:.3f}" for a in sp.actuation)
                    out(f"setpoint {sp.seq} {state} execution {sp.execution}: {act}")
            for st in status_sub.receive_all():
                status = st
            for s in stats_sub.receive_all():
                if args.set_id is not None and s.set_id != args.set_id:
                    continue
                d = stats_dict(s)
                stats.append(d)
                if args.json:
                    out(json.dumps({"kind": "stats", **d}))
                else:
                    errors = " ".join(f"{e:.2f}" for e in d["errors_mm"])
                    out(
                        f"stats: set {s.set_id} execution {s.execution}/{s.executions}: "
                        f"errors mm [{errors}] mean {d['mean_mm']:.2f} max {d['max_mm']:.2f} "
                        f"({s.reconditions} re-conditionings)"
                    )
            now = time.monotonic()
            if now >= next_report and not args.json and not args.every_setpoint:
                rate = (count - reported[0]) / max(now - reported[1], 1e-3)
                reported = (count, now)
                next_report = now + 1.0
                if last is None:
                    out("setpoints: none yet")
                else:
                    act = " ".join(f"{a:.3f}" for a in last.actuation)
                    out(
                        f"setpoints: {count} ({rate:.0f}/s), "
                        f"{sa.ControllerState.name_of(last.state)}, actuation {act}"
                    )
            if args.stats is not None and len(stats) >= args.stats:
                break
            # The setpoint buffer holds 4: at 500 Hz poll well within 8 ms.
            time.sleep(0.002)
    except KeyboardInterrupt:
        pass

    summary = {
        "kind": "summary",
        "namespace": ns,
        "seconds": round(time.monotonic() - start, 3),
        "setpoints": count,
        "missed": missed,
        "states": dict(states),
        "last_state": sa.ControllerState.name_of(last.state) if last else None,
        "last_actuation": list(last.actuation) if last else None,
        "status": status_dict(status) if status else None,
        "stats": stats,
    }
    if args.json:
        out(json.dumps(summary))
    else:
        out(
            f"{count} setpoints ({missed} missed) in {summary['seconds']} s, "
            f"last state {summary['last_state']}; {len(stats)} executions' stats"
        )
        if status:
            d = status_dict(status)
            out(
                f"status: {d['state']}, {d['rate_hz']:.0f} Hz, model "
                f"{'loaded' if d['model_loaded'] else 'missing'}, {d['ticks']} ticks"
            )
        if count == 0:
            out(f"no setpoint on {sa.service_name(ns, 'setpoint')}: is the stack running?")
    return 0 if count > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
