"""The companion's parameters: the list over its configuration, the file beside the
configuration that keeps what a ground station set, checked at start as the TOML is."""

from __future__ import annotations

import pytest
from support.loopback_fc import LoopbackFc

from companion.app import CompanionApp
from companion.cli import main
from companion.config import load_config, parse_config
from companion.controller import Controller, ControllerSettings
from companion.fc_link import FcLink
from companion.params import CompanionParams, with_params_file
from m4.airframe import load_airframe
from m4.mavlink import FC_SYSTEM_ID, mavlink
from m4.mavlink.link import UdpLink
from m4.params import NAME_MAX
from m4.toml_fields import ConfigError


def _config(tmp_path, params: str | None = None, extra: str = ""):
    path = tmp_path / "companion.toml"
    path.write_text(f'{extra}[link]\nsigning = false\n')
    if params is not None:
        (tmp_path / "companion.params.toml").write_text(params)
    return path


def test_every_name_is_ardupilot_style_and_the_settable_ones_are_the_detectors_and_the_delay_warning():
    table = CompanionParams(load_config(None)).table
    assert all(len(p.name) <= NAME_MAX and p.name.replace("_", "").isalnum() and p.name.isupper()
               for p in table.params)
    settable = {p.name for p in table.params if p.settable}
    assert settable == {n for n in settable if n.startswith("DET_")} | {"LINK_DELAY_WARN"}
    assert {"NMPC_HORIZON", "NMPC_DT", "NMPC_W_POS_N", "CTRL_RATE_HZ"} <= {p.name for p in table.params} - settable
    assert all(p.read_only_why for p in table.params if not p.settable)


def test_the_params_file_lies_beside_the_configuration_unless_it_says_where(tmp_path):
    assert load_config(_config(tmp_path)).params_path == tmp_path / "companion.params.toml"
    elsewhere = load_config(_config(tmp_path, extra='params_file = "state/p.toml"\n'))
    assert elsewhere.params_path == tmp_path / "state" / "p.toml"
    assert load_config(None).params_path is None


def test_the_params_file_is_applied_over_the_configuration(tmp_path):
    config = with_params_file(load_config(_config(tmp_path, "DET_CHI2_MIN = 40\nLINK_DELAY_WARN = 0.25\n")))
    assert config.fault_detector.chi2_min == 40.0
    assert config.link.delay_warning_s == 0.25
    assert config.nmpc.horizon == 5


@pytest.mark.parametrize("text, message", [
    ("DET_NOPE = 1\n", "DET_NOPE: no such parameter"),
    ("DET_CHI2_MIN = 0.5\n", "DET_CHI2_MIN: out of range [1, 1000], got 0.5"),
    ("DET_DEFICIT_MIN = 0\n", "DET_DEFICIT_MIN: out of range (0, 30], got 0"),
    ("NMPC_HORIZON = 8\n", "NMPC_HORIZON: read-only (the NMPC is compiled for it at start: change it in the "
                           "configuration and restart), got 8"),
    ("DET_CONFIRM = true\n", "DET_CONFIRM must be a number, got True"),
])
def test_a_bad_entry_stops_the_start_in_one_line_naming_it(tmp_path, capsys, text, message):
    path = _config(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        with_params_file(load_config(path))
    assert str(e.value) == f"{tmp_path / 'companion.params.toml'} {message}"
    assert main(["run", "--config", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("m4-companion: error:") and message in lines[0]


def test_a_set_retunes_the_running_detector_and_keeps_the_configuration_in_step():
    changes = []
    params = CompanionParams(load_config(None), changes.append)
    assert params.table.set("DET_CONFIRM", 0.2) is None
    assert params.table.set("NMPC_DT", 0.05).reason == "read-only"
    assert [c.fault_detector.confirm_s for c in changes] == [0.2]
    assert params.config.fault_detector.confirm_s == 0.2 and params.config.nmpc.dt_s == 0.1


def test_the_companions_parameters_answer_the_ids_its_link_sends_as(wait_until):
    """A companion on another component (192) answers a parameter read addressed to that
    component, as the component it sends as."""
    second = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER2
    link = UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, second)
    config = parse_config({"control": {"rate_hz": 50.0}, "link": {"fc_url": "udpin:127.0.0.1:0"}}, "test")
    app = CompanionApp(config, FcLink(link), Controller(ControllerSettings.of(config)))
    fc = LoopbackFc(link.local_port, load_airframe())
    try:
        fc.join(app)
        fc.link.send(mavlink.MAVLink_param_request_read_message(FC_SYSTEM_ID, second, b"", 0))
        values = []
        answered = wait_until(lambda: app.poll() or values.extend(m for m in fc.received() if m.get_type() == "PARAM_VALUE")
                              or values)
    finally:
        fc.close()
        link.close()
    assert answered and values[0].get_srcComponent() == second
