"""Every server geoloc starts listens on loopback only, unless its expose flag is given.

The house rule (docs/conventions.md, docs/tour_viewer.md): any server binds 127.0.0.1 unless a flag
says otherwise. Each case starts the server the way a user does (a ``geoloc`` process, or
the campaign's own ``local_cluster`` in a process of its own), then reads the listening
sockets of that process and of every child it started (the rerun web viewer is a child
process; Dask's workers and nannies are) from the kernel, through psutil, and fails on any
address that is not loopback. The cases with ``--host 0.0.0.0`` check the reader is not
blind: there the kernel must show the wildcard address, and the verb must say so.
"""

from __future__ import annotations

import ipaddress
import os
import queue
import re
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time

import pytest

psutil = pytest.importorskip("psutil")  # a dependency of dask.distributed


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def listening(pid: int) -> list[tuple[str, int]]:
    """(address, port) of every listening TCP socket and bound UDP socket of ``pid`` and its descendants."""
    procs = [psutil.Process(pid)]
    procs += procs[0].children(recursive=True)
    out = []
    for p in procs:
        try:
            conns = p.net_connections(kind="inet")
        except (psutil.NoSuchProcess, psutil.ZombieProcess):
            continue
        for c in conns:
            tcp_listen = c.type == socket.SOCK_STREAM and c.status == psutil.CONN_LISTEN
            udp_bound = c.type == socket.SOCK_DGRAM and c.laddr and not c.raddr
            if tcp_listen or udp_bound:
                out.append((c.laddr.ip, c.laddr.port))
    return out


def is_loopback(ip: str) -> bool:
    addr = ipaddress.ip_address(ip.split("%")[0])
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        addr = addr.ipv4_mapped
    return addr.is_loopback


def _drain(stream, sink) -> None:
    for line in iter(stream.readline, ""):
        sink(line)


def start(argv, env, ready: str, timeout_s: float = 240.0):
    """Start ``argv``; return (process, the first stdout line matching ``ready``).

    The timeout covers a first run that compiles the numba kernels (about 50 s here) on a
    busy 2-core machine. Both pipes are read by threads: a ``select`` on the pipe followed by
    a buffered ``readline`` misses a line that came in the same chunk as the one before
    (viser's banner and geoloc's line), and waited the whole timeout for it (seen in a full
    suite); stderr is kept (``proc.err_lines``) so that a chatty process never blocks on it.
    """
    proc = subprocess.Popen(
        argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True
    )
    lines: queue.Queue = queue.Queue()
    proc.err_lines = []
    proc.readers = [
        threading.Thread(target=_drain, args=(proc.stdout, lines.put), daemon=True),
        threading.Thread(target=_drain, args=(proc.stderr, proc.err_lines.append), daemon=True),
    ]
    for t in proc.readers:
        t.start()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            if proc.poll() is not None:
                proc.readers[1].join(5)
                raise AssertionError(f"{argv} exited {proc.returncode}: {''.join(proc.err_lines)[-2000:]}")
            continue
        if re.search(ready, line):
            return proc, line
    stop(proc)
    raise AssertionError(f"{argv} did not print {ready!r} within {timeout_s} s")


def stop(proc) -> str:
    """Stop ``proc`` (Ctrl-C, then SIGTERM, then SIGKILL) and its children; return its stderr."""
    kids = []
    try:
        kids = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        pass
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        if proc.poll() is not None:
            break
        proc.send_signal(sig)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            pass
    for k in kids:  # a child left behind by a parent that was killed
        try:
            k.kill()
        except psutil.NoSuchProcess:
            pass
    for t in proc.readers:  # the pipes close with the process (and its children)
        t.join(10)
    return "".join(proc.err_lines)


@pytest.fixture
def env(tmp_path):
    e = dict(os.environ)
    e["HOME"] = str(tmp_path)  # the rerun CLI writes its analytics config under ~/.config
    e["PYTHONUNBUFFERED"] = "1"
    return e


def check(proc, expose: bool, ports) -> list[tuple[str, int]]:
    """The process tree's sockets: all loopback without ``expose``; with it, the wildcard on ``ports``."""
    socks = listening(proc.pid)
    seen = {p for _, p in socks}
    assert set(ports) <= seen, f"the servers' ports {ports} are not among the listening sockets {socks}"
    outside = [(ip, p) for ip, p in socks if not is_loopback(ip)]
    if expose:
        assert {p for ip, p in outside if ip in ("0.0.0.0", "::")} >= set(ports), socks
    else:
        assert not outside, f"listening outside loopback without an expose flag: {outside} (all: {socks})"
    return socks


@pytest.mark.parametrize("expose", [False, True], ids=["default", "host-0.0.0.0"])
def test_geoloc_log_serve_binds_loopback(env, expose):
    web, grpc = free_port(), free_port()
    argv = [
        sys.executable,
        "-m",
        "geoloc",
        "log",
        "flight_scan",
        "--serve",
        "--web-port",
        str(web),
        "--grpc-port",
        str(grpc),
    ] + (["--host", "0.0.0.0"] if expose else [])
    proc, line = start(argv, env, r"web viewer: http")
    try:
        socks = check(proc, expose, (web, grpc))
        assert len(socks) >= 2
        if not expose:
            assert f"http://127.0.0.1:{web}/" in line and f"127.0.0.1:{grpc}/proxy" in line
            import urllib.request

            with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as r:  # the viewer's page
                assert r.status == 200 and b"<html" in r.read(2000).lower()
    finally:
        err = stop(proc)
    if expose:
        assert "warning: listening on every interface" in err and str(web) in err


@pytest.mark.parametrize("expose", [False, True], ids=["default", "host-0.0.0.0"])
def test_geoloc_view_binds_loopback(env, expose):
    argv = [sys.executable, "-m", "geoloc", "view", "--scenario", "limb", "--no-browser", "--port", "0"]
    argv += ["--host", "0.0.0.0"] if expose else []
    proc, line = start(argv, env, r"geoloc view: http")
    try:
        port = int(re.search(r":(\d+)\s", line).group(1))
        check(proc, expose, (port,))
    finally:
        err = stop(proc)
    if expose:
        assert "warning: listening on 0.0.0.0" in err


@pytest.mark.parametrize("processes", [True, False], ids=["worker-processes", "worker-threads"])
def test_campaign_local_cluster_binds_loopback(env, processes):
    # The cluster of run_campaign(scheduler="local"), started by the campaign's own function
    # in a process of its own (so no other test's sockets are counted).
    code = textwrap.dedent(f"""
        import sys
        from geoloc.workflows.campaign import local_cluster
        with local_cluster(workers=2, processes={processes}) as cluster:
            port = cluster.scheduler.http_server.port
            print("cluster up", cluster.scheduler_address, "dashboard", port, flush=True)
            sys.stdin.read()
    """)
    proc, line = start([sys.executable, "-c", code], env, r"cluster up")
    try:
        dashboard = int(line.split()[-1])
        socks = check(proc, False, (dashboard,))
        # the scheduler, its dashboard, and with processes each worker's and nanny's servers
        assert len(socks) >= (6 if processes else 1), socks
    finally:
        proc.stdin.close()
        stop(proc)
