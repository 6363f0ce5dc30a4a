"""A real Mosquitto for the site bus's tests: a free loopback port, a broker there with the test's
settings (a password file, an ACL file, a TLS listener), and the files it needs, made here:
passwords with Mosquitto's own mosquitto_passwd, a CA and the broker's certificate with openssl.
Debian's mosquitto, mosquitto-clients and openssl (.ci/run installs the first two)."""

from __future__ import annotations

import getpass
import os
import shutil
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

MOSQUITTO = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if os.path.exists("/usr/sbin/mosquitto") else None)
SUB = shutil.which("mosquitto_sub")
PUB = shutil.which("mosquitto_pub")
PASSWD = shutil.which("mosquitto_passwd")  # Debian's mosquitto package, beside the broker
OPENSSL = shutil.which("openssl")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class Tls:
    """A CA of the test's own, the broker's certificate (for 127.0.0.1) signed by it, and another
    CA that signed nothing of the broker's."""

    ca: Path
    cert: Path
    key: Path
    other_ca: Path


def make_tls(folder: Path) -> Tls:
    def openssl(*args: str | Path) -> None:
        assert OPENSSL is not None
        subprocess.run([OPENSSL, *map(str, args)], check=True, capture_output=True, timeout=120)

    f = folder
    for name in ("ca", "other"):
        openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f / f"{name}.key", "-out", f / f"{name}.pem",
                "-days", "2", "-subj", f"/CN=rfhoming test {name}")
    openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f / "broker.key", "-out", f / "broker.csr",
            "-subj", "/CN=127.0.0.1")
    (f / "san.cnf").write_text("subjectAltName=IP:127.0.0.1\n")
    openssl("x509", "-req", "-in", f / "broker.csr", "-CA", f / "ca.pem", "-CAkey", f / "ca.key", "-CAcreateserial",
            "-out", f / "broker.pem", "-days", "2", "-extfile", f / "san.cnf")
    return Tls(f / "ca.pem", f / "broker.pem", f / "broker.key", f / "other.pem")


def password_file(folder: Path, users: dict[str, str]) -> Path:
    """Mosquitto's password file for ``users`` (name -> password), made by mosquitto_passwd."""
    assert PASSWD is not None
    path = folder / "passwd"
    path.unlink(missing_ok=True)
    for user, password in users.items():
        subprocess.run([PASSWD, *([] if path.exists() else ["-c"]), "-b", str(path), user, password], check=True,
                       timeout=60, capture_output=True)
    return path


def start(folder: Path, port: int, settings: str = "allow_anonymous true\n", *, tls_port: int | None = None,
          tls: Tls | None = None) -> subprocess.Popen[bytes]:
    """Mosquitto on 127.0.0.1:``port`` (and a TLS listener on ``tls_port``) with ``settings``,
    no persistence; returned once every listener takes a connection. It runs as this user: run as
    root, Mosquitto reads its files as user "mosquitto", which pytest's tmp_path (0700) shuts out."""
    assert MOSQUITTO is not None
    lines = ["per_listener_settings false", settings.strip(), "persistence false", f"user {getpass.getuser()}",
             f"listener {port} 127.0.0.1"]
    if tls_port is not None:
        assert tls is not None
        lines += [f"listener {tls_port} 127.0.0.1", f"cafile {tls.ca}", f"certfile {tls.cert}", f"keyfile {tls.key}"]
    conf = folder / f"mosquitto-{port}.conf"
    conf.write_text("\n".join(lines) + "\n")
    proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60  # a hang guard
    for listening in (port, tls_port):
        while listening is not None:
            try:
                socket.create_connection(("127.0.0.1", listening), timeout=1).close()
                break
            except OSError:
                assert proc.poll() is None, f"mosquitto ended (exit code {proc.returncode}); its config:\n" \
                                            f"{conf.read_text()}"
                assert time.monotonic() < deadline, "mosquitto did not start listening within 60 s"
                time.sleep(0.05)
    return proc


def stop(proc: subprocess.Popen[bytes]) -> None:
    proc.terminate()
    proc.wait(30)
