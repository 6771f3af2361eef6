"""What a process tree listens on: the listening TCP and UDP sockets and the Unix sockets of a
process and its descendants, read from the system (psutil), for tests of what a command exposes."""

from __future__ import annotations

import socket
from dataclasses import dataclass

import psutil


@dataclass(frozen=True)
class Listener:
    pid: int
    name: str  # the process's command line, shortened
    kind: str  # "tcp", "udp" or "unix"
    address: str  # "host:port", or the Unix socket's path ("" for an unnamed one)


def process_tree(pid: int) -> list[psutil.Process]:
    try:
        root = psutil.Process(pid)
        return [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def listeners(pid: int) -> list[Listener]:
    """Every listening socket of `pid` and its descendants: TCP in LISTEN state, bound UDP sockets,
    and Unix sockets with a path."""
    found = []
    for process in process_tree(pid):
        try:
            name = " ".join(process.cmdline()[1:4])
            connections = process.net_connections(kind="all")
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        for c in connections:
            if c.family == socket.AF_UNIX:
                if c.laddr:
                    found.append(Listener(process.pid, name, "unix", str(c.laddr)))
            elif c.type == socket.SOCK_STREAM and c.status == psutil.CONN_LISTEN:
                found.append(Listener(process.pid, name, "tcp", f"{c.laddr.ip}:{c.laddr.port}"))
            elif c.type == socket.SOCK_DGRAM and c.laddr and not c.raddr:
                found.append(Listener(process.pid, name, "udp", f"{c.laddr.ip}:{c.laddr.port}"))
    return found
