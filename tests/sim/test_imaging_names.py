"""The imaging words are the CLI's: a former name is refused with a line naming what it meant."""

import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.imaging import make_imaging


def test_realistic_is_refused_naming_the_camera_and_imaging_it_meant(capsys):
    meant = "--camera mavic2pro --imaging camera"
    with pytest.raises(ConfigError, match=rf"'realistic' is not a setting.*{meant}"):
        make_imaging("realistic")
    assert make_imaging("camera").name == "camera"  # the CLI's words still resolve

    from uav_struct_env.datasets.__main__ import main as dataset
    from uav_struct_env.study.study import main as study

    for command in (lambda: study(["--imaging", "realistic"]),
                    lambda: dataset(["out", "--imaging", "realistic"])):
        with pytest.raises(SystemExit) as stop:
            command()
        assert stop.value.code == 2
        last = capsys.readouterr().err.strip().splitlines()[-1]
        assert "--imaging" in last and meant in last, last
