"""Serve recordings in Rerun's web viewer on loopback, idle-friendly.

`rerun --serve-web FILE.rrd` keeps a core busy while idle, and the Python serve_* functions bind
0.0.0.0. So we start the real rerun binary (not the Python shim, which would leave an orphan when
terminated) as an idle proxy bound to 127.0.0.1, and push the data into it from Python.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import time
import urllib.request
from pathlib import Path
from urllib.parse import quote


def _die_with_parent() -> None:
    """In the child: get SIGTERM when the parent dies, even by SIGKILL (Linux prctl). Linux ties
    this to the *thread* that started the child: start viewers from a thread that lives as long
    as they should."""
    try:
        import ctypes
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)    # PR_SET_PDEATHSIG = 1
    except OSError:
        pass


def _free_port(host: str) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class RerunWeb:
    """A loopback web viewer + gRPC proxy. Use as a context manager; close() stops it."""

    def __init__(self, host: str = "127.0.0.1", web_port: int | None = None, grpc_port: int | None = None):
        import rerun_cli
        binary = Path(rerun_cli.__file__).parent / "rerun"
        self.host = host
        self.grpc_port = grpc_port or _free_port(host)
        self.web_port = web_port or _free_port(host)
        while self.web_port == self.grpc_port:      # two free ports asked one after the other can be one
            self.web_port = _free_port(host)
        self.proc = subprocess.Popen(
            [str(binary), "--serve-web", "--bind", host, "--port", str(self.grpc_port),
             "--web-viewer-port", str(self.web_port)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
            preexec_fn=_die_with_parent)
        deadline = time.time() + 30
        while True:
            try:
                urllib.request.urlopen(f"http://{host}:{self.web_port}/", timeout=0.5).read(1)
                break
            except OSError:
                if self.proc.poll() is not None or time.time() > deadline:
                    self.close()
                    raise RuntimeError("the Rerun web viewer did not start") from None
                time.sleep(0.1)

    @property
    def grpc_uri(self) -> str:
        return f"rerun+http://{self.host}:{self.grpc_port}/proxy"

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.web_port}/?url={quote(self.grpc_uri, safe='')}"

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self) -> "RerunWeb":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def push_file(web: RerunWeb, path: Path):
    """Send a crowdcam recording and its layout to the viewer; returns the connected stream."""
    import rerun as rr
    from rerun.chunk import RrdReader

    from pipeline.rerun_log import make_blueprint, read_blueprint_desc

    desc = read_blueprint_desc(path)
    reader = RrdReader(str(path))
    entry = reader.recordings()[0]
    rec = rr.RecordingStream(entry.application_id, recording_id=entry.recording_id)
    rec.connect_grpc(web.grpc_uri)
    rr.send_chunks(reader.store(), recording=rec)
    rec.send_blueprint(make_blueprint(desc))      # send_chunks does not forward the file's blueprint
    rec.flush()
    return rec


def wait_until_interrupted(poll: float = 0.5, announce: str | None = None) -> None:
    """Sleep (idle) until Ctrl-C or SIGTERM. Handlers are installed explicitly: a process started
    in the background by a shell inherits SIGINT ignored. `announce` is printed (stdout) once they
    are in place, so that a Ctrl-C right after it is a clean stop, never a traceback."""
    def stop(*_):
        raise KeyboardInterrupt
    old = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        if announce:
            print(announce, flush=True)
        while True:
            time.sleep(poll)
    except KeyboardInterrupt:
        pass
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
