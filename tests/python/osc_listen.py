"""An OSC listener from another codebase (python-osc) for tests/people_outputs.rs.

Binds UDP on 127.0.0.1 (a free port), prints the port on the first line, then prints every
OSC message it receives as one JSON array [address, arg, ...] per line, and exits after the
first /scanfuse/crossing (or after 60 s without one).
"""

import json
import socket
import sys

from pythonosc.osc_packet import OscPacket

sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("127.0.0.1", 0))
sock.settimeout(60)
print(sock.getsockname()[1], flush=True)
while True:
    try:
        data, _ = sock.recvfrom(65536)
    except socket.timeout:
        sys.exit("no /scanfuse/crossing within 60 s")
    for timed in OscPacket(data).messages:
        message = timed.message
        print(json.dumps([message.address, *message.params]), flush=True)
        if message.address == "/scanfuse/crossing":
            sys.exit(0)
