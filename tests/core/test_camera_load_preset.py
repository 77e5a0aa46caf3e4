"""``Camera.load`` takes what every ``--camera`` option takes: a TOML file or a preset name
(issue 28 part 5)."""

import pytest

from skyfix.camera import PRESETS, Camera, camera_from_preset
from skyfix.errors import CameraError, UnknownNameError
from skyfix.presets import load_preset, preset_names


@pytest.mark.parametrize("name", preset_names())
def test_every_hardware_preset_loads_by_name(name):
    cam = Camera.load(name)
    assert cam == Camera.from_dict(load_preset(name)["camera"])
    assert Camera.load(name.upper()) == cam


def test_camera_only_presets_and_files_still_load(tmp_path):
    only = [n for n in PRESETS if n not in preset_names()]
    for name in only:
        assert Camera.load(name) == camera_from_preset(name)
    path = tmp_path / "generic"  # a file named like a preset is the file
    cam = Camera.from_fov(320, 240, 9.0)
    path.write_text(cam.to_toml())
    assert Camera.load(path) == cam


def test_an_unknown_name_lists_the_presets_and_a_missing_toml_is_a_file_error():
    with pytest.raises(UnknownNameError, match="unknown camera preset or file 'nope'; choose one of .*sunsat"
                       ):
        Camera.load("nope")
    with pytest.raises(CameraError, match="cannot read camera file nope.toml"):
        Camera.load("nope.toml")
