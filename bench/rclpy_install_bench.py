"""What ROS 2 Jazzy's rclpy wheels cost a test environment: install time and disk, into a fresh
venv with nothing else, downloads included (no pip cache), and the time of one rclpy start.

    python bench/rclpy_install_bench.py --json

Prints the packages and versions pip installed, the seconds of ``pip install``, the venv's size
before and after, and the seconds of ``python -c "import rclpy; rclpy.init()"`` in that venv
(the wheels' bootstrapper starts that Python once more with LD_LIBRARY_PATH), with the load
average before and after. Needs the network to PyPI; Linux x86_64, CPython 3.11-3.14.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

WHEELS = ["ros-jazzy-rclpy", "ros-jazzy-rmw-fastrtps-cpp", "ros-jazzy-nav-msgs", "ros-jazzy-sensor-msgs",
          "ros-jazzy-geometry-msgs"]


def size_mb(folder: Path) -> float:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file() and not f.is_symlink()) / 1e6


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true", help="one JSON object instead of lines")
    args = p.parse_args()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="rclpy-bench-") as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        python = str(venv / "bin" / "python")
        before = size_mb(venv)
        began = time.monotonic()
        subprocess.run([python, "-m", "pip", "install", "-q", "--no-cache-dir", *WHEELS], check=True)
        install_s = time.monotonic() - began
        after = size_mb(venv)
        listed = json.loads(subprocess.run([python, "-m", "pip", "list", "--format", "json"], check=True,
                                           capture_output=True, text=True).stdout)
        began = time.monotonic()
        subprocess.run([python, "-c", "import rclpy; rclpy.init(); rclpy.shutdown()"], check=True,
                       env={**os.environ, "ROS_LOG_DIR": tmp})
        start_s = time.monotonic() - began
    result = {"install_s": round(install_s, 1), "venv_mb_before": round(before), "venv_mb_after": round(after),
              "wheels_mb": round(after - before), "rclpy_start_s": round(start_s, 2),
              "packages": {p["name"]: p["version"] for p in listed if p["name"] not in ("pip", "setuptools")},
              "load_before": [round(v, 2) for v in load_before], "load_after": [round(v, 2) for v in os.getloadavg()],
              "python": sys.version.split()[0]}
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")


if __name__ == "__main__":
    main()
