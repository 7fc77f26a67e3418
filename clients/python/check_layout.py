#!/usr/bin/env python3
"""Prints the layout of every softarm payload mirror (``softarm_ipc.PAYLOADS``) as one JSON object:

    {"Setpoint": {"size": 80, "align": 8, "fields": {"seq": 0, ...},
                  "types": {"seq": "u64", "actuation": "[f64; 6]", ...},
                  "type_name": "softarm::Setpoint"}, ...}

``types`` are in the notation of Rust's ``std::any::type_name`` (module paths stripped), so
``tests/python.rs`` compares all of it with the Rust types (``size_of``, ``align_of``,
``offset_of!``, the ``#[type_name]`` strings).

With ``--services`` it prints the service settings instead:

    {"pubsub": {"setpoint": {"payload": "softarm::Setpoint", "history": 1,
                             "subscriber_max_buffer_size": 4, "max_publishers": 2,
                             "max_subscribers": 8, "max_nodes": 16}, ...},
     "request_response": {"waypoints": {"request": ..., "response": ..., "max_clients": 8,
                          "max_servers": 1, "max_nodes": 16,
                          "max_active_requests_per_client": 2,
                          "max_response_buffer_size": 2}, ...}}

With ``--enums``: ``{"ControllerState": {"IDLE": 0, ...}, "DriverState": {...}}``.

Needs only the standard library (not iceoryx2).
"""

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import softarm_ipc as sa  # noqa: E402


def services() -> dict:
    return {
        "pubsub": {
            name: {
                "payload": s.payload.type_name(),
                "history": s.history,
                "subscriber_max_buffer_size": s.subscriber_max_buffer_size,
                "max_publishers": s.publishers,
                "max_subscribers": s.subscribers,
                "max_nodes": s.nodes,
            }
            for name, s in sa.SERVICES.items()
        },
        "request_response": {
            name: {
                "request": s.request.type_name(),
                "response": s.response.type_name(),
                "max_clients": s.clients,
                "max_servers": s.servers,
                "max_nodes": s.nodes,
                "max_active_requests_per_client": s.active_requests_per_client,
                "max_response_buffer_size": s.response_buffer,
            }
            for name, s in sa.REQUEST_RESPONSE.items()
        },
    }


def main() -> None:
    if "--services" in sys.argv[1:]:
        out = services()
    elif "--enums" in sys.argv[1:]:
        out = {
            e.__name__: {m.name: m.value for m in e}
            for e in (sa.ControllerState, sa.DriverState)
        }
    else:
        out = {t.__name__: sa.layout(t) for t in sa.PAYLOADS}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
