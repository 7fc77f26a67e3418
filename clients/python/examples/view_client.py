#!/usr/bin/env python3
"""A client of `softarm view` that speaks the Foxglove WebSocket protocol itself (v1 as
https://github.com/foxglove/ws-protocol documents it), independent of the `foxglove` crate
that serves it: `websockets` for the connection, `protobuf` to decode the scene with the schema
the server advertises (a FileDescriptorSet), `json` for the rest.

It offers the subprotocol the protocol documents, `foxglove.websocket.v1`, unless
`--subprotocol NAME` (repeated, or a comma list) says otherwise: `softarm view` also accepts
the `foxglove` crate's names for the same messages, `foxglove.sdk.v1` and `foxglove.sdk.v1.1`
(the latter changes how schemas are advertised, which this client does not read). A server
that refuses every name offered ends it with exit code 2 (with `--json`, an object saying the
HTTP status and the reason the server gave).

    python3 -m pip install websockets protobuf
    softarm view &                       # or [view] enabled = true and `softarm up`
    python3 clients/python/examples/view_client.py --url ws://127.0.0.1:8765 --seconds 5

prints the channels the server advertises, then a line a second: messages per topic, the
controller's state, the arm's modelled tip against the tracker. `--json` prints one JSON
object at the end instead (the channels and their schemas, the counts, the last `status`,
every `stats`, the scene's entities and how far the arm's tip was from the tracker sample of
the same `seq`); `--set-id ID --stats N` stops once N executions of set ID are in
and the controller is idle again.

`--slow S` plays a client that stops reading: it subscribes to everything, reads nothing for
S seconds (the sockets' buffers on the way fill, then the server's queue for it), then reads
what comes (for up to `--seconds`, or until setpoints went missing) and reports how many
setpoints it never got (gaps in their `seq`): the server drops for a slow client rather than
stalling or growing.
"""

import argparse
import base64
import json
import struct
import sys
import time

from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

DOCUMENTED = "foxglove.websocket.v1"
MESSAGE_DATA = 0x01


def scene_decoder(channel):
    """The SceneUpdate class built from the channel's advertised FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


def schema_ok(channel):
    """Whether the advertised schema is what its encoding says: a JSON Schema titled as the
    channel's schema name, or a protobuf FileDescriptorSet that defines it."""
    if channel["schemaEncoding"] == "jsonschema":
        s = json.loads(channel["schema"])
        return s.get("title") == channel["schemaName"] and s.get("type") == "object"
    if channel["schemaEncoding"] == "protobuf":
        scene_decoder(channel)
        return True
    return False


class Client:
    def __init__(self, ws):
        self.ws = ws
        self.server = None
        self.channels = {}  # id -> advertised channel
        self.subscriptions = {}  # subscription id -> channel
        self.statuses = []

    def control(self, text):
        m = json.loads(text)
        if m["op"] == "serverInfo":
            self.server = m
        elif m["op"] == "advertise":
            for c in m["channels"]:
                self.channels[c["id"]] = c
        elif m["op"] == "status":
            self.statuses.append(m)

    def until_advertised(self, topics, timeout=10):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            have = {c["topic"] for c in self.channels.values()}
            if self.server is not None and topics <= have:
                return
            self.recv(end - time.monotonic())
        raise SystemExit(f"no advertisement of {sorted(topics)} in {timeout} s: "
                         f"got {sorted(c['topic'] for c in self.channels.values())}")

    def subscribe_all(self):
        subs = []
        for i, c in enumerate(sorted(self.channels.values(), key=lambda c: c["id"]), 1):
            self.subscriptions[i] = c
            subs.append({"id": i, "channelId": c["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def recv(self, timeout):
        """One message: (channel, log time ns, payload bytes) for data, None otherwise."""
        try:
            m = self.ws.recv(timeout=max(timeout, 0.001))
        except TimeoutError:
            return None
        if isinstance(m, str):
            self.control(m)
            return None
        if m[0] != MESSAGE_DATA:
            return None
        sub, log_time = struct.unpack_from("<IQ", m, 1)
        return self.subscriptions.get(sub), log_time, m[13:]


class Tally:
    """What the messages say: counts, the last status, the stats, the scene against the
    tracker."""

    def __init__(self, decoders, decoded):
        self.decoders = decoders
        # The JSON topics worth decoding: the rest are counted (a test beside others on two
        # cores should not spend a core on JSON it does not look at).
        self.decoded = decoded
        self.counts = {}
        self.bytes = 0
        self.status = None
        self.stats = []
        self.tracker = {}  # seq -> position, the newest few thousand
        self.arm = []  # (motor_state seq, tip)
        self.entities = set()
        self.setpoint_seqs = []

    def take(self, channel, data):
        topic = channel["topic"]
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.bytes += len(data)
        if channel["encoding"] == "json" and topic in self.decoded:
            v = json.loads(data)
            if topic == "status":
                self.status = v
            elif topic == "stats":
                self.stats.append(v)
            elif topic == "tracker":
                self.tracker[v["seq"]] = v["position"]
                if len(self.tracker) > 20000:
                    for k in sorted(self.tracker)[:10000]:
                        del self.tracker[k]
            elif topic == "setpoint":
                self.setpoint_seqs.append(v["seq"])
        elif topic == "scene":
            self.take_scene(self.decoders[channel["id"]].FromString(data))

    def take_scene(self, update):
        for e in update.entities:
            self.entities.add(e.id)
            if e.id != "arm":
                continue
            meta = {kv.key: kv.value for kv in e.metadata}
            tip = e.lines[-1].points[-1]
            self.arm.append((int(meta["motor_state.seq"]), [tip.x, tip.y, tip.z]))

    def tip_errors(self):
        """Distance (m) of the arm's tip from the tracker sample of the same seq, per pair."""
        out = []
        for seq, tip in self.arm:
            p = self.tracker.get(seq)
            if p is not None and None not in p:
                out.append(sum((a - b) ** 2 for a, b in zip(tip, p)) ** 0.5)
        return out

    def gaps(self):
        """Setpoints never received between the first and the last received."""
        s = sorted(set(self.setpoint_seqs))
        return sum(b - a - 1 for a, b in zip(s, s[1:]) if b > a + 1)


def refusals(client):
    """Asks the server to take a publication and parameters; it must refuse both."""
    client.ws.send(json.dumps({"op": "advertise", "channels": [
        {"id": 1, "topic": "estop", "encoding": "json", "schemaName": "softarm::EstopState"}]}))
    client.ws.send(json.dumps({"op": "getParameters", "parameterNames": []}))


def channels_summary(client):
    return {c["topic"]: {"encoding": c["encoding"], "schemaName": c["schemaName"],
                         "schemaEncoding": c["schemaEncoding"], "schema_ok": schema_ok(c)}
            for c in client.channels.values()}


def run(args):
    # A slow client's library stops reading its socket once 4 messages wait in it.
    with connect(args.url, subprotocols=args.subprotocols, max_size=None,
                 max_queue=4 if args.slow else 16, open_timeout=10) as ws:
        return session(Client(ws), args)


def subprotocols(given):
    """The names to offer: every --subprotocol, each possibly a comma list."""
    names = [n.strip() for g in given or [DOCUMENTED] for n in g.split(",")]
    return [n for n in names if n]


def session(client, args):
    client.until_advertised({"setpoint", "status", "scene"})
    decoders = {c["id"]: scene_decoder(c) for c in client.channels.values()
                if c["encoding"] == "protobuf"}
    if not (args.json or args.slow):
        for c in sorted(client.channels.values(), key=lambda c: c["topic"]):
            print(f"{c['topic']:<17} {c['encoding']:<9} {c['schemaName']}")
    refusals(client)
    client.subscribe_all()
    decoded = {"status", "stats", "tracker"} | ({"setpoint"} if args.slow else set())
    tally = Tally(decoders, decoded)
    if args.slow:
        return slow(client, tally, args)
    start = last = time.monotonic()
    while time.monotonic() - start < args.seconds:
        got = client.recv(0.1)
        if got is not None and got[0] is not None:
            tally.take(got[0], got[2])
        if args.set_id is not None and done(tally, args):
            break
        if not args.json and time.monotonic() - last >= 1:
            last = time.monotonic()
            errors = tally.tip_errors()
            state = tally.status and tally.status["state"]
            tip = f"{1e3 * max(errors):.3f}" if errors else "-"
            print(f"{sum(tally.counts.values())} messages, state {state}, tip vs tracker max "
                  f"{tip} mm over {len(errors)} pairs")
    return report(client, tally, time.monotonic() - start)


def done(tally, args):
    """N executions of the set are in and the controller has said it is idle after them."""
    n = sum(1 for s in tally.stats if s["set_id"] == args.set_id)
    st = tally.status
    return n >= args.stats and st is not None and st["set_id"] == 0 and st["state"] == 0


def slow(client, tally, args):
    """Reads nothing for `args.slow` s, then reads for up to `args.seconds` s, or until it has
    seen setpoints go missing (checked once a second: what follows a gap is live)."""
    time.sleep(args.slow)
    start = checked = time.monotonic()
    while time.monotonic() - start < args.seconds:
        got = client.recv(0.5)
        if got is not None and got[0] is not None:
            tally.take(got[0], got[2])
        if time.monotonic() - checked >= 1:
            if tally.gaps():
                break
            checked = time.monotonic()
    out = report(client, tally, time.monotonic() - start)
    s = sorted(set(tally.setpoint_seqs))
    out["setpoints"] = {"received": len(s), "first": s[0] if s else None,
                        "last": s[-1] if s else None, "missing": tally.gaps()}
    return out


def report(client, tally, seconds):
    errors = tally.tip_errors()
    return {
        "server": {k: client.server.get(k) for k in ("name", "capabilities", "metadata")},
        "subprotocol": client.ws.subprotocol,
        "channels": channels_summary(client),
        "statuses": [s["message"] for s in client.statuses],
        "seconds": seconds,
        "counts": tally.counts,
        "payload_bytes": tally.bytes,
        "status": tally.status,
        "stats": tally.stats,
        "scene": {"entities": sorted(tally.entities), "arm_updates": len(tally.arm),
                  "pairs": len(errors), "max_tip_error_m": max(errors) if errors else None},
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--url", default="ws://127.0.0.1:8765")
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--json", action="store_true")
    p.add_argument("--set-id", type=int)
    p.add_argument("--stats", type=int, default=1)
    p.add_argument("--slow", type=float, default=0.0, metavar="S")
    p.add_argument("--subprotocol", action="append", metavar="NAME",
                   help=f"a subprotocol to offer (repeat, or a comma list; default {DOCUMENTED})")
    args = p.parse_args()
    args.subprotocols = subprotocols(args.subprotocol)
    try:
        out = run(args)
    except InvalidStatus as e:
        r = e.response
        reason = r.body.decode("utf-8", "replace").strip() if r.body else r.reason_phrase
        if args.json:
            print(json.dumps({"refused": {"status": r.status_code, "reason": reason,
                                          "offered": args.subprotocols}}))
        else:
            print(f"{args.url} refused the subprotocols {args.subprotocols}: HTTP "
                  f"{r.status_code} ({reason})", file=sys.stderr)
        return 2
    if args.json or args.slow:
        print(json.dumps(out))
    else:
        print(f"{sum(out['counts'].values())} messages in {out['seconds']:.1f} s: {out['counts']}")
    return 0 if out["counts"] else 1


if __name__ == "__main__":
    sys.exit(main())
