import hashlib
import threading
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest

from calib.core import datasets
from calib.core.datasets import (
    CAMSPEC,
    DatasetFetchError,
    PinnedFile,
    fetch_datasets,
    load_collection,
    makabe2025_split,
    read_camspec_txt,
    read_rawtoaces_json,
    read_rgb_csv,
    resolve_data_dir,
)
from calib.core.errors import InputError


def test_readers_normalise_each_camera(tmp_path):
    csv = tmp_path / "Canon_600D_Jiang-et-al-2013.csv"
    csv.write_text("wavelength,red,green,blue\n400,0.1,0.2,0.4\n410,0.2,0.8,0.3\n")
    curves = read_rgb_csv(csv)
    assert curves.values.max() == pytest.approx(1.0)
    camspec = tmp_path / "camspec.txt"
    rows = "\n".join(
        "\t".join(str(v) for v in np.linspace(0.1, k, 33)) + "\t" for k in (0.5, 2.0, 1.0)
    )
    camspec.write_text(
        f"http://example\n400nm-720nm, step 10nm\n---------\n\nCam A\n{rows}\nCam B\n{rows}\n"
    )
    records = read_camspec_txt(camspec)
    assert [r.camera for r in records] == ["Cam A", "Cam B"]
    assert records[0].sensitivity.values.max() == pytest.approx(1.0)
    json_file = tmp_path / "cam.json"
    json_file.write_text(
        '{"header": {"manufacturer": "acme", "model": "x1"}, "spectral_data": {"data": {"main": '
        '{"380": [0.1, 0.2, 0.3], "385": [0.2, 0.4, 0.1]}}}}'
    )
    camera = read_rawtoaces_json(json_file)
    assert camera.name == "acme x1" and camera.values.max() == pytest.approx(1.0)


def test_bad_json_names_the_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(InputError, match=r"bad\.json"):
        read_rawtoaces_json(bad)


def test_missing_data_says_how_to_fetch(tmp_path, monkeypatch):
    monkeypatch.delenv("SPECTRAL_RIG_DATA", raising=False)
    monkeypatch.setattr(datasets, "default_data_dir", lambda: tmp_path / "nowhere")
    with pytest.raises(InputError, match="rig data fetch"):
        resolve_data_dir()
    with pytest.raises(InputError, match="--data-dir"):
        load_collection(CAMSPEC, tmp_path / "absent")


def test_colour_science_cameras_need_no_files():
    records = load_collection("colour-science")
    names = {r.name for r in records}
    assert {"Nikon 5100 (NPL)", "Canon EOS 5D Mark II (rawtoaces)"} <= names


def _fake_mirror(tmp_path, corrupt: bool = False):
    """A mirror with one pinned file; returns the pinned list to use."""
    payload = b"wavelength,red,green,blue\n400,0.1,0.2,0.3\n410,0.3,1.0,0.2\n"
    pinned = PinnedFile(
        "demo",
        "owner/repo",
        "0" * 40,
        "data/a [x].csv",
        hashlib.sha256(payload).hexdigest(),
        len(payload),
    )
    target = tmp_path / "mirror" / "owner" / "repo" / ("0" * 40) / "data" / "a [x].csv"
    target.parent.mkdir(parents=True)
    target.write_bytes(payload + (b"junk" if corrupt else b""))
    return pinned


def test_fetch_from_file_url_verifies_and_skips(tmp_path, monkeypatch):
    pinned = _fake_mirror(tmp_path)
    monkeypatch.setattr(datasets, "pinned_files", lambda collections=None: [pinned])
    base = (tmp_path / "mirror").as_uri()
    report = fetch_datasets(tmp_path / "data", base_url=base)
    assert report.downloaded == ["demo/data/a [x].csv"]
    assert (tmp_path / "data" / "demo" / "data" / "a [x].csv").is_file()
    again = fetch_datasets(tmp_path / "data", base_url=base)
    assert again.already_present == ["demo/data/a [x].csv"] and not again.downloaded


def test_fetch_rejects_a_corrupted_download_without_leaving_a_file(tmp_path, monkeypatch):
    pinned = _fake_mirror(tmp_path, corrupt=True)
    monkeypatch.setattr(datasets, "pinned_files", lambda collections=None: [pinned])
    with pytest.raises(DatasetFetchError, match="checksum"):
        fetch_datasets(tmp_path / "data", base_url=(tmp_path / "mirror").as_uri())
    assert not (tmp_path / "data" / "demo" / "data" / "a [x].csv").exists()


def test_fetch_over_loopback_http(tmp_path, monkeypatch):
    pinned = _fake_mirror(tmp_path)
    monkeypatch.setattr(datasets, "pinned_files", lambda collections=None: [pinned])

    class QuietHandler(SimpleHTTPRequestHandler):
        def log_message(self, format: str, *args: object) -> None:
            pass

    handler = partial(QuietHandler, directory=str(tmp_path / "mirror"))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        report = fetch_datasets(
            tmp_path / "data", base_url=f"http://127.0.0.1:{server.server_port}", timeout_s=5
        )
    finally:
        server.shutdown()
        server.server_close()
    assert report.downloaded == ["demo/data/a [x].csv"]


def test_pinned_manifest_covers_the_measured_collections():
    files = datasets.pinned_files()
    assert len(files) == 94
    assert all(len(f.sha256) == 64 and f.size_bytes > 0 for f in files)
    with pytest.raises(InputError, match="downloadable"):
        datasets.pinned_files(["nope"])


@pytest.mark.shared_data
def test_shared_collections_and_the_makabe_split(shared_camera_data):
    train, test = makabe2025_split(shared_camera_data)
    assert len(train) == 44 and len(test) == 5
    assert {r.camera for r in test} == {
        "Canon 600D",
        "iPhone 12-Pro-Max",
        "Olympus EPL2",
        "Pentax K5",
        "Samsung Galaxy-S20",
    }
    for name, count in (("jiang-2013-camspec", 28), ("butcherg-ssf-data", 32), ("rawtoaces", 11)):
        records = load_collection(name, shared_camera_data)
        assert len(records) == count
        assert all(r.sensitivity.values.max() == pytest.approx(1.0) for r in records)
    status = datasets.collection_status(shared_camera_data)
    assert all(valid == total for valid, total in status.values())
