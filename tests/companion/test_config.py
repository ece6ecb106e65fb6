import dataclasses
import math
from pathlib import Path

import pytest

from m4.airframe import load_airframe
from companion.config import CompanionConfig, load_config
from companion.core.fault_detector import FaultDetectorConfig
from companion.core.nmpc_config import NmpcConfig
from m4.toml_fields import ConfigError

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy" / "companion.toml"


def write(tmp_path, text, name="companion.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_defaults_fly_the_reference_airframe_at_50_hz_on_the_sitl_link(tmp_path):
    c = load_config()
    assert c.rate_hz == 50.0 and c.control_period_s == pytest.approx(0.02)
    assert c.nmpc == NmpcConfig(control_period_s=0.02, time_budget_share=0.5)
    assert c.fault_detector == FaultDetectorConfig()
    assert c.airframe == load_airframe() and c.airframe_path is None
    assert c.mission.waypoints == () and c.mission_path is None
    assert c.link.fc_url == "udpin:127.0.0.1:14550" and c.link.signing_key_path is None
    assert c.link.telemetry_timeout_s == 0.3 and (c.link.fc_system_id, c.link.fc_component_id) == (1, 1)
    assert not c.feed.enabled
    from_file = load_config(write(tmp_path, ""))          # an empty file is all defaults, but for where
    assert dataclasses.replace(from_file, params_path=None) == c       # its parameters are kept: beside it


def test_example_file_loads_and_differs_from_the_defaults_only_in_link_feed_log_folder_and_priority():
    c = load_config(EXAMPLE)
    assert c.realtime_priority == 40 and CompanionConfig().realtime_priority == 0   # a laptop: normal priority
    assert c.params_path == Path("/var/lib/m4/companion.params.toml")       # /etc is read-only to the service
    assert c.link.fc_url == "/dev/ttyTHS1,921600"
    assert c.feed.enabled and c.feed.vehicle == "m4" and c.feed.zenoh_config == Path("/etc/m4/zenoh-companion.json5")
    assert c.log.dir == Path("/var/log/m4")                  # the tests' default is $M4_LOG_DIR
    # A default changed in code and not in the example (or the reverse) shows up here.
    defaults = CompanionConfig()
    assert dataclasses.replace(c, link=defaults.link, feed=defaults.feed, realtime_priority=0, params_path=None,
                               log=dataclasses.replace(c.log, dir=defaults.log.dir)) == load_config()


def _file_keys(settings) -> set[str]:
    return {f.name[:-4] + "_deg" if f.name.endswith("_rad") else f.name for f in dataclasses.fields(settings)}


def test_example_file_names_every_key_of_every_table():
    text = EXAMPLE.read_text()
    c = CompanionConfig()
    keys = (_file_keys(c.nmpc) - {"weights", "control_period_s"} | _file_keys(c.nmpc.weights)
            | _file_keys(c.fault_detector) | _file_keys(c.reference) | _file_keys(c.touchdown)
            | {"rate_hz", "realtime_priority", "disturbance_gain", "airframe_file", "mission_file", "params_file",
               "fc_url",
               "signing", "signing_key_file", "signing_state_file", "telemetry_timeout_s", "fc_system_id",
               "fc_component_id"} | _file_keys(c.log))
    missing = sorted(k for k in keys if f"\n{k} = " not in text and f"\n# {k} = " not in text)
    assert not missing, f"deploy/companion.toml does not document {missing}"


def test_nmpc_table_maps_onto_the_nmpc_settings_with_angles_in_degrees(tmp_path):
    c = load_config(write(tmp_path, """
[control]
rate_hz = 50.0
[nmpc]
horizon = 20
dt_s = 0.05
roll_pitch_max_deg = 60.0
fixed_hip_deg = 45.0
codegen = false
[nmpc.weights]
position = [1.0, 2.0, 3.0]
thrust = 0.5
"""))
    n = c.nmpc
    assert (n.horizon, n.dt_s, n.codegen) == (20, 0.05, False)
    assert n.roll_pitch_max_rad == pytest.approx(math.radians(60)) and n.fixed_hip_rad == pytest.approx(math.radians(45))
    assert n.control_period_s == pytest.approx(0.02)
    assert n.weights.position == (1.0, 2.0, 3.0) and n.weights.thrust == 0.5
    assert n.weights.velocity == NmpcConfig().weights.velocity


def test_detector_reference_and_touchdown_tables_reach_their_settings(tmp_path):
    c = load_config(write(tmp_path, """
[fault_detector]
deficit_min_n = 3.0
confirm_s = 0.2
[reference]
accel_max_m_s2 = 1.0
[touchdown]
dwell_s = 0.5
"""))
    assert c.fault_detector.deficit_min_n == 3.0 and c.fault_detector.confirm_s == 0.2
    assert c.reference.accel_max_m_s2 == 1.0 and c.touchdown.dwell_s == 0.5


def test_relative_mission_and_airframe_files_are_found_beside_the_config(tmp_path):
    write(tmp_path, '[mission]\non_fault = "continue"\n[[mission.waypoint]]\nned_m = [5.0, 0.0, -2.0]\n', "m.toml")
    af_text = (Path(load_airframe.__code__.co_filename).parent / "airframes" / "m4_reference.toml").read_text()
    write(tmp_path, af_text.replace('name = "m4-reference"', 'name = "m4-copy"'), "af.toml")
    c = load_config(write(tmp_path, 'mission_file = "m.toml"\nairframe_file = "af.toml"\n'))
    assert c.mission.on_fault == "continue" and c.mission.waypoints[0].ned_m == (5.0, 0.0, -2.0)
    assert c.airframe.name == "m4-copy" and c.airframe_path == tmp_path / "af.toml"


@pytest.mark.parametrize("text, names", [
    ("rate = 10.0", "unknown key(s) rate"),
    ("[control]\nrate_hz = 0.0", "rate_hz"),
    ("[control]\nrate_hz = 150.0", "rate_hz"),
    ("[control]\nrate_hz = \"fast\"", "rate_hz"),
    ("[control]\nrealtime_priority = -1", "realtime_priority"),
    ("[control]\nrealtime_priority = 100", "realtime_priority"),
    ("[control]\nrealtime_priority = 50.0", "realtime_priority"),
    ("[control]\nrealtime_priority = true", "realtime_priority"),
    ("[control]\ncpu = -1", "cpu must be >= 0"),
    ("[control]\ncpu = 1.5", "cpu must be an integer"),
    ("[control]\nshortfall_cover = 1", "shortfall_cover"),
    ("[nmpc]\nhorizon = 0", "horizon"),
    ("[nmpc]\nhorizon = 2.5", "horizon"),
    ("[nmpc]\ndt_s = -0.1", "dt_s"),
    ("[nmpc]\nroll_pitch_max_deg = 120.0", "roll_pitch_max"),
    ("[nmpc]\ndisturbance_gain = 1.5", "disturbance_gain"),
    ("[nmpc]\nhorizn = 5", "horizn"),
    ("[nmpc.weights]\nposition = [1.0, 2.0]", "position"),
    ("[nmpc.weights]\nthrust = -1.0", "thrust"),
    ("[nmpc.weights]\nthrust = 0.0", "thrust"),
    ("[fault_detector]\nwindow_s = 0.0", "window_s"),
    ("[fault_detector]\nestimate_gain = 2.0", "estimate_gain"),
    ("[fault_detector]\nthreshold = 1.0", "threshold"),
    ("[reference]\naccel_max_m_s2 = 0.0", "accel_max_m_s2"),
    ("[touchdown]\ndwell_s = -1.0", "dwell_s"),
    ("[link]\nfc_url = \"serial:ttyS0\"", "fc_url"),
    ("[link]\nfc_url = \"udpin:127.0.0.1\"", "fc_url"),
    ("[link]\ntelemetry_timeout_s = 0.0", "telemetry_timeout_s"),
    ("[link]\nfc_system_id = 0", "fc_system_id"),
    ("[link]\nfc_component_id = 256", "fc_component_id"),
    ("[feed]\nvehicle = \"m4\"", "[feed]"),
    ("[feed]\nmode = \"router\"", "mode"),
    ("mission_file = \"missing.toml\"", "mission_file"),
    ("airframe_file = \"missing.toml\"", "airframe_file"),
    ("fc_mission_on_fault = \"land\"", "fc_mission_on_fault"),
])
def test_each_bad_key_or_value_is_rejected_with_its_name(tmp_path, text, names):
    with pytest.raises(ConfigError, match=names.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")):
        load_config(write(tmp_path, text))


@pytest.mark.parametrize("text, names", [
    ("[control]\nrate_hz = 1e-300", "rate_hz must be >= 5"),
    ("[nmpc]\ndt_s = 1e30", "dt_s must be <= 0.25"),
    ("[nmpc]\ndt_s = 0.001", "dt_s must be >= 0.01"),
    ("[nmpc]\nrk4_substeps = 1000", "rk4_substeps"),
    ("[nmpc]\nmax_iterations = 100000", "max_iterations"),
    ("[nmpc]\nroll_pitch_max_deg = 1.0", "roll_pitch_max_deg"),
    ("[nmpc]\nfixed_hip_deg = 120.0", "fixed_hip_deg"),                         # beyond the joints
    ("[nmpc]\ncost_tol_rel = 5.0", "cost_tol_rel"),
    ("[nmpc.weights]\nposition = [1e300, 20.0, 40.0]", "position"),
    ("[nmpc.weights]\nhip_accel = 1e-300", "hip_accel"),
    ("[nmpc.weights]\nterminal_scale = 1e9", "terminal_scale"),
    ("[nmpc.weights]\nhorizontal_saturated_scale = 2.0", "horizontal_saturated_scale must be <= 1"),
    ("[reference]\naccel_max_m_s2 = 1e9", "accel_max_m_s2"),
    ("[touchdown]\ndwell_s = 1e9", "dwell_s"),
    ("[touchdown]\nheight_tolerance_m = 2.0", "height_tolerance_m"),
    ("[upset]\ntilt_max_deg = 10.0", "tilt_max_deg"),
    ("[upset]\nground_s = 1e9", "ground_s"),
    ("[fault_detector]\nchi2_min = 1e300", "chi2_min"),
    ("[fault_detector]\ndeficit_min_n = 31.0", "deficit_min_n"),           # more than a rotor gives
    ("[fault_detector]\nconfirm_s = 100.0", "confirm_s"),
    ("[fault_detector]\nforce_model_error_n = 1e6", "force_model_error_n"),
    ("[link]\ntelemetry_timeout_s = 1e-9", "telemetry_timeout_s must be at least 3 control periods"),
    ("[link]\ndelay_warning_s = 1e-9", "delay_warning_s"),
    ("[log]\nmax_file_mb = 1e-300", "max_file_mb"),
    ("[log]\nmax_file_mb = 100.0\nmax_total_mb = 10.0", "max_total_mb"),
    ("[feed]\nlisten = \"tcp/127.0.0.1:7448\"\nmax_rate_hz = 1e300", "max_rate_hz"),
])
def test_a_value_outside_its_physical_range_is_rejected_with_its_name(tmp_path, text, names):
    with pytest.raises(ConfigError, match=names):
        load_config(write(tmp_path, text))


def test_the_telemetry_timeout_is_at_least_3_control_periods(tmp_path):
    with pytest.raises(ConfigError, match=r"telemetry_timeout_s must be at least 3 control periods \(0.6 s at 5 Hz;"):
        load_config(write(tmp_path, "[control]\nrate_hz = 5.0\n"))              # the default 0.3 s
    slow = load_config(write(tmp_path, "[control]\nrate_hz = 5.0\n[link]\ntelemetry_timeout_s = 0.6\n"))
    assert slow.link.telemetry_timeout_s == 0.6
    assert load_config(write(tmp_path, "[control]\nrate_hz = 10.0\n")).link.telemetry_timeout_s == 0.3


def test_the_real_time_iteration_flies_from_25_hz_and_the_sqp_below(tmp_path):
    assert load_config(write(tmp_path, "")).nmpc.scheme == "rti"
    assert load_config(write(tmp_path, "[control]\nrate_hz = 25.0\n")).nmpc.scheme == "rti"
    assert load_config(write(tmp_path, "[control]\nrate_hz = 10.0\n")).nmpc.scheme == "sqp"
    assert load_config(write(tmp_path, "[control]\nrate_hz = 50.0\n[nmpc]\nscheme = \"sqp\"\n")).nmpc.scheme == "sqp"
    with pytest.raises(ConfigError, match=r'\[nmpc\] scheme = "rti" needs a control rate of at least 25 Hz .* got 10 Hz'):
        load_config(write(tmp_path, "[control]\nrate_hz = 10.0\n[nmpc]\nscheme = \"rti\"\n"))
    with pytest.raises(ConfigError, match=r"\[nmpc\] scheme must be one of sqp, rti; got 'acados'"):
        load_config(write(tmp_path, "[nmpc]\nscheme = \"acados\"\n"))


def test_the_plan_reaches_the_next_solve_and_no_further_than_4_s(tmp_path):
    for text in ("[nmpc]\nhorizon = 40\ndt_s = 0.2",                                # an 8 s plan
                 "[control]\nrate_hz = 10.0\n[nmpc]\nhorizon = 5\ndt_s = 0.01"):   # 50 ms: ends before the next solve
        with pytest.raises(ConfigError, match=r"\[nmpc\] horizon x dt_s"):
            load_config(write(tmp_path, text))
    longest = load_config(write(tmp_path, "[nmpc]\nhorizon = 40\ndt_s = 0.1\n")).nmpc
    assert longest.horizon * longest.dt_s == pytest.approx(4.0)


def test_a_bad_mission_file_is_reported_with_its_own_key(tmp_path):
    write(tmp_path, '[mission]\non_fault = "panic"\n', "m.toml")
    with pytest.raises(ConfigError, match="on_fault"):
        load_config(write(tmp_path, 'mission_file = "m.toml"\n'))


def test_serial_and_network_links_are_accepted(tmp_path):
    for url in ("/dev/ttyTHS1,921600", "/dev/ttyACM0", "udpout:10.0.0.2:14550", "tcp:127.0.0.1:5760"):
        assert load_config(write(tmp_path, f'[link]\nfc_url = "{url}"\n')).link.fc_url == url


def test_missing_or_malformed_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "absent.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[control\n"))
