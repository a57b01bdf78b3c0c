"""Who holds a listening TCP port on this machine (Linux /proc), for a refusal that names it."""
from __future__ import annotations

import os
import re
from pathlib import Path

_ENDPOINT = re.compile(r"^(?:tcp|tls|quic|ws)/(?:\[[^\]]*\]|[^:/]*):(\d+)")
_LISTEN = "0A"  # TCP state LISTEN in /proc/net/tcp


def endpoint_port(endpoint: str) -> int | None:
    """The port of a zenoh endpoint like `tcp/0.0.0.0:7447` (None when it names none)."""
    match = _ENDPOINT.match(endpoint)
    return int(match.group(1)) if match else None


def _listening_inodes(port: int, proc: Path) -> set[str]:
    inodes: set[str] = set()
    for table in ("tcp", "tcp6"):
        try:
            lines = (proc / "net" / table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 9 and fields[3] == _LISTEN and int(fields[1].rsplit(":", 1)[1], 16) == port:
                inodes.add(fields[9])
    return inodes


def port_holder(port: int, proc: Path = Path("/proc")) -> str | None:
    """'pid N (command line)' of a process listening on `port`, or None if none is found (or not ours to see)."""
    inodes = _listening_inodes(port, proc)
    if not inodes:
        return None
    targets = {f"socket:[{inode}]" for inode in inodes}
    for pid_dir in proc.iterdir():
        if not pid_dir.name.isdigit():
            continue
        try:
            for fd in (pid_dir / "fd").iterdir():
                if os.readlink(fd) in targets:
                    cmdline = (pid_dir / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                    return f"pid {pid_dir.name} ({cmdline.strip()[:200]})"
        except OSError:  # another user's process, or gone meanwhile
            continue
    return "a process this user cannot inspect"
