"""The fake gphoto2 module keeps the real module's call surface, constants and error texts."""

from __future__ import annotations

import pytest

from mocks import fake_gphoto2
from mocks.fake_gphoto2 import FakeGphoto2, canon_eos_body, minimal_body
from mocks.fake_gphoto2 import camera as fake_camera
from mocks.fake_gphoto2 import constants as fake_constants
from mocks.fake_gphoto2.widgets import CameraWidget

real = pytest.importorskip("gphoto2", reason="python-gphoto2 wheel not installed")

#: Every method the driver (and the fake's tests) call on each object.
CALL_SURFACE: dict[str, tuple[type, tuple[str, ...]]] = {
    "Camera": (
        fake_camera.Camera,
        (
            "autodetect", "init", "exit", "get_config", "set_config", "get_single_config",
            "set_single_config", "capture", "wait_for_event", "file_get", "file_delete",
            "folder_list_files", "set_abilities", "set_port_info",
        ),
    ),
    "CameraWidget": (
        CameraWidget,
        (
            "get_name", "get_label", "get_type", "get_value", "set_value", "get_readonly",
            "count_children", "get_child", "get_children", "get_child_by_name", "count_choices",
            "get_choice", "get_choices", "get_range", "changed", "set_changed", "get_parent",
            "get_root",
        ),
    ),
    "CameraFile": (fake_camera.CameraFile, ("get_data_and_size", "get_mime_type", "get_name", "save")),
    "CameraList": (fake_camera.CameraList, ("get_name", "get_value", "count", "__len__")),
    "PortInfoList": (fake_camera.PortInfoList, ("load", "lookup_path", "count", "__getitem__")),
    "CameraAbilitiesList": (
        fake_camera.CameraAbilitiesList,
        ("load", "lookup_model", "get_abilities", "count", "__getitem__"),
    ),
}  # fmt: skip


@pytest.mark.parametrize("class_name", sorted(CALL_SURFACE))
def test_every_fake_method_exists_on_the_real_class(class_name: str) -> None:
    fake_class, methods = CALL_SURFACE[class_name]
    real_class = getattr(real, class_name)
    for method in methods:
        assert hasattr(fake_class, method), f"fake {class_name} lacks {method}"
        assert hasattr(real_class, method), f"real {class_name} has no {method}: fake drifted"


def test_constants_equal_the_real_ones() -> None:
    names = [n for n in dir(fake_constants) if n.startswith("GP_")]
    assert len(names) > 50
    for name in names:
        assert getattr(real, name) == getattr(fake_constants, name), name


def test_error_texts_equal_the_real_ones() -> None:
    for code, text in fake_constants.ERROR_STRINGS.items():
        assert real.gp_result_as_string(code) == text, code
    fake_error = fake_gphoto2.GPhoto2Error(-110)
    real_error = real.GPhoto2Error(-110)
    assert (fake_error.code, fake_error.string, str(fake_error)) == (
        real_error.code,
        real_error.string,
        str(real_error),
    )


def test_library_version_matches_the_wheel() -> None:
    gp = FakeGphoto2([])
    assert (
        gp.gp_library_version(gp.GP_VERSION_SHORT)[0]
        == (real.gp_library_version(real.GP_VERSION_SHORT)[0])
    )


# ------------------------------------------------------------------------- fake behaviour


def test_widget_tree_and_errors_behave_like_libgphoto2() -> None:
    gp = FakeGphoto2([canon_eos_body()])
    camera = gp.Camera()
    camera.init()
    root = camera.get_config()
    with pytest.raises(gp.GPhoto2Error) as caught:
        root.get_value()
    assert caught.value.code == gp.GP_ERROR_BAD_PARAMETERS
    shutter = root.get_child_by_name("shutterspeed")
    assert shutter.get_parent() is not None and shutter.get_root() is root
    with pytest.raises(gp.GPhoto2Error):
        root.get_child_by_name("nonexistent")
    with pytest.raises(TypeError):
        shutter.set_value(1)
    shutter.set_value("1/4")
    camera.set_config(root)
    assert camera.get_single_config("shutterspeed").get_value() == "1/4"
    widget = camera.get_single_config("shutterspeed")
    widget.set_value("1/3")  # not a choice: the widget takes it, the camera does not
    with pytest.raises(gp.GPhoto2Error) as caught:
        camera.set_single_config("shutterspeed", widget)
    assert caught.value.code == gp.GP_ERROR_BAD_PARAMETERS
    camera.exit()
    with pytest.raises(gp.GPhoto2Error):
        camera.get_config()
    assert gp.calls_after_exit == ["get_config"]


def test_autodetect_ports_and_models() -> None:
    gp = FakeGphoto2([canon_eos_body(), minimal_body()])
    cameras = gp.Camera.autodetect()
    assert [(cameras.get_name(i), cameras.get_value(i)) for i in range(len(cameras))] == [
        ("Canon EOS 5D Mark III", "usb:001,004"),
        ("GP VC", "usb:002,003"),
    ]
    abilities = gp.CameraAbilitiesList()
    abilities.load()
    with pytest.raises(gp.GPhoto2Error) as caught:
        abilities.lookup_model("Sony")
    assert caught.value.code == gp.GP_ERROR_MODEL_NOT_FOUND
    ports = gp.PortInfoList()
    ports.load()
    camera = gp.Camera()
    camera.set_port_info(ports[ports.lookup_path("usb:009,009")])
    with pytest.raises(gp.GPhoto2Error) as caught:
        camera.init()
    assert caught.value.code == gp.GP_ERROR_IO_USB_FIND
    with pytest.raises(ValueError, match="two bodies on one port"):
        FakeGphoto2([canon_eos_body(), canon_eos_body()])
