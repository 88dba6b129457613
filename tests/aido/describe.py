"""Print AIDO's protocol descriptions as a zuper-nodes node answers ``wrapper.describe_protocol``.

Run with a Python that has aido-protocols-daffy and zuper-nodes-z6 (``requirements.txt``); zuper's
schema writer needs Python <= 3.10 (on 3.11 it fails on ``typing.Any``, the crash the real agent node
shows). ``python describe.py simulator > ../data/aido/simulator-protocol-description.json`` made the
test data file (aido-protocols-daffy 6.1.1, zuper-ipce-z6 6.1.2, Python 3.10.13).
"""

import json
import logging
import sys

logging.disable(logging.CRITICAL)

from aido_schemas import protocol_agent_DB20_timestamps  # noqa: E402
from aido_schemas.schemas import protocol_simulator_DB20_timestamps  # noqa: E402
from zuper_ipce import IESO, ipce_from_object  # noqa: E402
from zuper_nodes_wrapper.meta_protocol import ProtocolDescription, basic_protocol  # noqa: E402

PROTOCOLS = {"agent": protocol_agent_DB20_timestamps, "simulator": protocol_simulator_DB20_timestamps}

if __name__ == "__main__":
    desc = ProtocolDescription(data=PROTOCOLS[sys.argv[1]], meta=basic_protocol)
    json.dump(ipce_from_object(desc, ieso=IESO(with_schema=False)), sys.stdout, indent=1)
    print()
