"""``data fetch`` through pooch: hashes, retries of what may be transient, none of what is not, and
one line at the first file when the host cannot be reached (offline). No real network: a loopback
server, a closed loopback port, and a name lookup that fails as it does offline."""

from __future__ import annotations

import hashlib
import socket
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import SimpleNamespace

import pooch.core
import pytest

from calib.cli.app import main as calib_main
from calib.core import datasets
from calib.core.datasets import (
    DatasetFetchError,
    DatasetSourceUnreachable,
    PinnedFile,
    fetch_datasets,
)

PAYLOAD = b"wavelength,red,green,blue\n400,0.1,0.2,0.3\n410,0.3,1.0,0.2\n"


def _pinned(name: str = "a.csv", payload: bytes = PAYLOAD) -> PinnedFile:
    digest = hashlib.sha256(payload).hexdigest()
    return PinnedFile("demo", "owner/repo", "0" * 40, f"data/{name}", digest, len(payload))


SHUTDOWN_POLL_S = 0.02


class _Server:
    """A loopback HTTP server answering each path with a scripted list of statuses."""

    def __init__(self, answers: dict[str, list[int]]) -> None:
        self.answers = answers
        self.requests: list[str] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                outer.requests.append(self.path)
                script = outer.answers.get(self.path.rsplit("/", 1)[-1], [404])
                status = script.pop(0) if len(script) > 1 else script[0]
                body = PAYLOAD if status == 200 else b"no"
                self.send_response(status)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: object) -> None:
                pass

        self.http = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.http.server_port}"

    def __enter__(self) -> _Server:
        # Polled for shutdown every 20 ms (the default 0.5 s is what each test would wait at its end).
        serve = {"poll_interval": SHUTDOWN_POLL_S}
        threading.Thread(target=self.http.serve_forever, kwargs=serve, daemon=True).start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.http.shutdown()
        self.http.server_close()


@pytest.fixture
def pooch_waits(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """The waits pooch asks for between a file's attempts (1 s, then 2 s), recorded, not slept:
    what is tested is which attempts are made, not how long pooch waits between them."""
    waits: list[float] = []
    monkeypatch.setattr(pooch.core, "time", SimpleNamespace(sleep=waits.append))
    return waits


@pytest.fixture
def closed_port() -> Iterator[int]:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        yield probe.getsockname()[1]  # bound, never listening: a connection is refused


def _many_files(monkeypatch: pytest.MonkeyPatch, count: int = 40) -> list[PinnedFile]:
    files = [_pinned(f"f{i}.csv") for i in range(count)]
    monkeypatch.setattr(datasets, "pinned_files", lambda collections=None: files)
    return files


def test_a_refused_connection_stops_at_the_first_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, closed_port: int
) -> None:
    _many_files(monkeypatch)
    done: list[str] = []
    with pytest.raises(DatasetSourceUnreachable) as caught:
        fetch_datasets(
            tmp_path / "data",
            base_url=f"http://127.0.0.1:{closed_port}",
            progress=lambda i, n, path: done.append(path),
        )
    message = str(caught.value)
    assert "\n" not in message and f"cannot reach 127.0.0.1:{closed_port}" in message
    assert "connection refused" in message and "--base-url" in message
    assert done == []  # not one file further, no retry
    assert not list((tmp_path / "data").rglob("*.csv"))


def test_offline_a_name_that_does_not_resolve_is_asked_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _many_files(monkeypatch)
    lookups: list[str] = []

    def offline(host: str, *args: object, **kwargs: object) -> list[object]:
        lookups.append(host)
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

    monkeypatch.setattr(socket, "getaddrinfo", offline)
    with pytest.raises(DatasetSourceUnreachable, match="does not resolve; offline"):
        fetch_datasets(tmp_path / "data")
    assert lookups == ["raw.githubusercontent.com"]


def test_the_cli_says_offline_in_one_line(
    tmp_path: Path, closed_port: int, capsys: pytest.CaptureFixture[str]
) -> None:
    arguments = ["data", "fetch", "--data-dir", str(tmp_path), "-q"]
    with pytest.raises(SystemExit) as exit_:
        calib_main([*arguments, "--base-url", f"http://127.0.0.1:{closed_port}"])
    assert exit_.value.code == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("calib: failed: cannot reach 127.0.0.1")


def test_a_broken_download_is_retried_and_a_missing_file_is_not(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, pooch_waits: list[float]
) -> None:
    files = [_pinned("flaky.csv"), _pinned("gone.csv")]
    monkeypatch.setattr(datasets, "pinned_files", lambda collections=None: files)
    server = _Server({"flaky.csv": [503, 200], "gone.csv": [404]})
    with server, pytest.raises(DatasetFetchError, match="1 of 2 files failed") as caught:
        fetch_datasets(tmp_path / "data", base_url=server.url, retries=1)
    assert [path.rsplit("/", 1)[-1] for path in server.requests] == [
        "flaky.csv",
        "flaky.csv",
        "gone.csv",
    ]
    assert (tmp_path / "data" / "demo" / "data" / "flaky.csv").read_bytes() == PAYLOAD
    assert caught.value.failures == [
        ("demo/data/gone.csv", f"{server.url}/owner/repo/{'0' * 40}/data/gone.csv: HTTP 404")
    ]
    assert pooch_waits == [1]  # one wait, before the flaky file's second attempt


def test_a_corrupted_download_is_retried_then_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, pooch_waits: list[float]
) -> None:
    files = [_pinned("a.csv", PAYLOAD + b"x")]  # the server sends PAYLOAD: the hash differs
    monkeypatch.setattr(datasets, "pinned_files", lambda collections=None: files)
    server = _Server({"a.csv": [200]})
    with server, pytest.raises(DatasetFetchError, match="checksum mismatch"):
        fetch_datasets(tmp_path / "data", base_url=server.url, retries=1)
    assert len(server.requests) == 2
    assert not list((tmp_path / "data").rglob("a.csv"))
    assert pooch_waits == [1]
