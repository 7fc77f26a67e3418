#!/usr/bin/env python3
"""A ROS 2 peer of `softarm ros2` without ROS: Eclipse Cyclone DDS (`pip install cyclonedds`),
the DDS that ROS 2's rmw_cyclonedds_cpp uses, with the ROS 2 messages written out as IDL
structs under their DDS type names (`sensor_msgs::msg::dds_::JointState_`, ...) on the DDS
topics ROS 2 names `rt/<topic>`.

It watches the bridge's topics for --seconds (or until --until says it has seen enough) and
prints one JSON object: the topics the bridge publishes and subscribes with their type names,
every setpoint JointState (its stamp in ns and its positions as the bits of each float64, for
an exact comparison), counts, the newest tracker position and the
newest diagnostics. Before watching it can send a way-point set (--waypoints FILE, a softarm
way-point TOML file, as trajectory_msgs/MultiDOFJointTrajectory) or an e-stop (--estop,
std_msgs/Empty), each once the bridge's reader has matched.

    python3 ros2_peer.py --namespace /softarm/arm1 --seconds 5
    python3 ros2_peer.py --namespace /softarm/arm1 --waypoints config/waypoints/demo.toml \
        --until accepted --seconds 30
    python3 ros2_peer.py --namespace /softarm/arm1 --estop --until engaged --seconds 30

--localhost (default) keeps Cyclone DDS on 127.0.0.1 with unicast discovery, as ROS 2 does
for ROS_LOCALHOST_ONLY=1 / ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; the bridge's
`ros2.discovery = "localhost"` is the other half. --domain is ROS_DOMAIN_ID.
"""

import argparse
import json
import os
import struct
import sys
import time
import tomllib
from dataclasses import dataclass, field

LOCALHOST = """<CycloneDDS><Domain id="any"><General>
<Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>
<AllowMulticast>false</AllowMulticast></General>
<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>40</MaxAutoParticipantIndex>
<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>"""


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--namespace", required=True, help="the bridge's ROS 2 namespace")
    p.add_argument("--domain", type=int, default=0, help="ROS_DOMAIN_ID (ros2.domain_id)")
    p.add_argument("--subnet", action="store_true", help="discover on every interface")
    p.add_argument("--seconds", type=float, default=5.0, help="longest to watch")
    p.add_argument("--until", choices=["running", "stale", "engaged", "accepted", "refused", "setpoints"],
                   help="stop watching once the diagnostics say so (or 50 setpoints came)")
    p.add_argument("--waypoints", help="send this way-point file (TOML) as a trajectory")
    p.add_argument("--estop", action="store_true",
                   help="send an e-stop, again every 0.5 s until --until is reached")
    p.add_argument("--best-effort", action="store_true",
                   help="send the e-stop best-effort (as a sensor-data QoS publisher would)")
    return p.parse_args()


args = parse_args()
if not args.subnet:
    # Read by Cyclone DDS when the first participant is made.
    os.environ["CYCLONEDDS_URI"] = LOCALHOST

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, \
    BuiltinTopicDcpsSubscription  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.internal import InvalidSample  # noqa: E402
from cyclonedds.idl.types import float64, int32, sequence, uint8, uint32  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402


# The ROS 2 messages (common_interfaces, Jazzy), field for field.
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Empty(IdlStruct, typename="std_msgs::msg::dds_::Empty_"):
    structure_needs_at_least_one_member: uint8 = 0


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class PointStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PointStamped_"):
    header: Header = field(default_factory=Header)
    point: Point = field(default_factory=Point)


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8 = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = field(default_factory=list)


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class MultiDOFJointTrajectoryPoint(
        IdlStruct, typename="trajectory_msgs::msg::dds_::MultiDOFJointTrajectoryPoint_"):
    transforms: sequence[Transform] = field(default_factory=list)
    velocities: sequence[Twist] = field(default_factory=list)
    accelerations: sequence[Twist] = field(default_factory=list)
    time_from_start: Duration = field(default_factory=Duration)


@dataclass
class MultiDOFJointTrajectory(
        IdlStruct, typename="trajectory_msgs::msg::dds_::MultiDOFJointTrajectory_"):
    header: Header = field(default_factory=Header)
    joint_names: sequence[str] = field(default_factory=list)
    points: sequence[MultiDOFJointTrajectoryPoint] = field(default_factory=list)


# ROS 2's default QoS for these topics: reliable, volatile, keep last.
RELIABLE = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.Volatile,
               Policy.History.KeepLast(64))
BEST_EFFORT = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile,
                  Policy.History.KeepLast(1))


def ns_ros_time(t):
    return t.sec * 1_000_000_000 + t.nanosec


def trajectory(path):
    """A softarm way-point file as a MultiDOFJointTrajectory: one transform per point."""
    with open(path, "rb") as f:
        w = tomllib.load(f)
    points = []
    for p in w["point"]:
        x, y, z = p["position_m"]
        t = p["t_s"]
        points.append(MultiDOFJointTrajectoryPoint(
            transforms=[Transform(translation=Vector3(x, y, z))],
            time_from_start=Duration(int(t), round((t - int(t)) * 1e9))))
    return MultiDOFJointTrajectory(header=Header(frame_id="base"), joint_names=["tip"],
                                   points=points)


def matched_writer(dp, name, kind, qos, deadline):
    """A writer once a reader of the bridge has matched it; None if none did in time."""
    writer = DataWriter(dp, Topic(dp, name, kind), qos=qos)
    while not writer.get_matched_subscriptions():
        if time.monotonic() > deadline:
            return None
        time.sleep(0.05)
    return writer


def diagnostics_of(msg):
    out = {}
    for s in msg.status:
        part = s.name.split(": ", 1)[-1]
        out[part] = {"level": int(s.level), "message": s.message,
                     "values": {kv.key: kv.value for kv in s.values}}
    return out


def done(until, diag, setpoints):
    if until == "setpoints":
        return len(setpoints) >= 50
    if not diag:
        return False
    if until == "running":
        return diag["controller"]["level"] == 0
    if until == "stale":
        # The stack gone: neither the controller nor the driver heard from.
        return diag["controller"]["level"] >= 2 and diag["driver"]["level"] >= 2
    if until == "engaged":
        return diag["estop"]["values"].get("engaged") == "true"
    if until == "accepted":
        return diag["ros2 bridge"]["values"].get("last_set_id", "0") != "0"
    if until == "refused":
        return diag["ros2 bridge"]["values"].get("sets_refused", "0") != "0"
    return False


def main():
    ns = args.namespace.rstrip("/")
    dp = DomainParticipant(args.domain)
    pubs = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
    subs = BuiltinDataReader(dp, BuiltinTopicDcpsSubscription)
    readers = {
        "setpoint": DataReader(dp, Topic(dp, f"rt{ns}/setpoint", JointState), qos=RELIABLE),
        "joint_states": DataReader(dp, Topic(dp, f"rt{ns}/joint_states", JointState),
                                   qos=RELIABLE),
        "tracker": DataReader(dp, Topic(dp, f"rt{ns}/tracker", PointStamped), qos=RELIABLE),
        "diagnostics": DataReader(dp, Topic(dp, f"rt{ns}/diagnostics", DiagnosticArray),
                                  qos=RELIABLE),
    }
    start = time.monotonic()
    deadline = start + args.seconds
    sent = {}
    waypoints = None
    if args.waypoints:
        waypoints = matched_writer(dp, f"rt{ns}/waypoints", MultiDOFJointTrajectory, RELIABLE,
                                   deadline)
        sent["waypoints"] = False
    estop = None
    if args.estop:
        # Sent again until the bridge says it is engaged: a best-effort sample that came
        # before the bridge knew this writer is lost, and an e-stop twice is one e-stop.
        qos = BEST_EFFORT if args.best_effort else RELIABLE
        estop = matched_writer(dp, f"rt{ns}/estop", Empty, qos, deadline)
        sent["estop"] = estop is not None
    last_estop = 0.0

    topics = {"published": {}, "subscribed": {}}
    counts = {k: 0 for k in readers}
    setpoints, joint_names, tracker, diag, levels = [], None, None, None, []
    reached = False
    while time.monotonic() < deadline and not reached:
        if waypoints is not None and diag is not None and not sent["waypoints"]:
            # Written once the bridge has been heard from and had a moment to match this
            # writer: RustDDS drops a sample from a writer it has not matched yet, and a
            # reliable writer does not always repair that (seen with Cyclone DDS, under load).
            time.sleep(1.0)
            for _ in range(3):
                waypoints.write(trajectory(args.waypoints))
                if waypoints.wait_for_acks(duration(seconds=5)):
                    break
            sent["waypoints"] = True
        if estop is not None and time.monotonic() - last_estop >= 0.5:
            estop.write(Empty())
            last_estop = time.monotonic()
        for kind, reader in (("published", pubs), ("subscribed", subs)):
            for e in reader.take(N=100):
                # An endpoint that went away comes as a sample with its key alone.
                if e.topic_name and e.topic_name.startswith(f"rt{ns}/"):
                    topics[kind][e.topic_name] = e.type_name
        got = 0
        for name, reader in readers.items():
            for m in reader.take(N=200):
                if isinstance(m, InvalidSample):
                    # A writer that went away (the bridge stopping): its key alone, no data.
                    continue
                got += 1
                counts[name] += 1
                if name == "setpoint":
                    # The positions' bits: the reader compares them exactly.
                    bits = [struct.unpack("<Q", struct.pack("<d", v))[0] for v in m.position]
                    setpoints.append([ns_ros_time(m.header.stamp), bits])
                    joint_names = list(m.name)
                elif name == "tracker":
                    tracker = {"frame_id": m.header.frame_id,
                               "point": [m.point.x, m.point.y, m.point.z]}
                elif name == "diagnostics":
                    diag = diagnostics_of(m)
                    levels.append(diag["controller"]["level"])
        reached = args.until is not None and done(args.until, diag, setpoints)
        if not got:
            time.sleep(0.005)
    print(json.dumps({
        "topics": topics, "sent": sent, "counts": counts, "joint_names": joint_names,
        "setpoints": setpoints, "tracker": tracker, "diagnostics": diag,
        "controller_levels": levels, "until": args.until, "reached": reached,
        "seconds": round(time.monotonic() - start, 3),
    }))
    return 0 if args.until is None or reached else 1


if __name__ == "__main__":
    sys.exit(main())
