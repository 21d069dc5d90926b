"""An independent SCIP client reads `scanfuse emulate`: hokuyolx (PyPI), which nobody here wrote.

Usage: python driver_hokuyolx.py HOST PORT N
Prints one JSON object per line: {"cmd": "GD"|"ME", "ranges": [...], "intensities": [...]}.
"""
import json
import sys

from hokuyolx import HokuyoLX


def main():
    host, port, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    # Connects, %ST, TM0, TM1 x10, TM2, PP, BM: the whole hokuyolx handshake.
    laser = HokuyoLX(addr=(host, port), timeout=5)
    _, scan = laser.get_dist()
    print(json.dumps({"cmd": "GD", "ranges": [int(v) for v in scan]}), flush=True)
    for i, (scan, _, _) in enumerate(laser.iter_intens()):
        print(json.dumps({
            "cmd": "ME",
            "ranges": [int(v) for v in scan[:, 0]],
            "intensities": [int(v) for v in scan[:, 1]],
        }), flush=True)
        if i + 1 >= n:
            break
    laser.close()


if __name__ == "__main__":
    main()
