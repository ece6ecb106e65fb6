import pytest

from m4.scenario import load_mission, load_scenario
from m4.toml_fields import ConfigError
from sitl.scenarios import builtin_names, resolve, scenario_path
from m4.fault_kind import FaultKind

GOOD = """
name = "t"
duration_s = 10.0
[start]
ned_m = [1.0, 2.0, -3.0]
yaw_deg = 90.0
[mission]
on_fault = "continue"
[[mission.waypoint]]
ned_m = [5.0, 0.0, -3.0]
speed_m_s = 2.0
hold_s = 1.0
[mission.land]
at_s = 8.0
[[fault]]
at_s = 6.0
rotor = 2
loss = 0.5
kind = "damage"
until_s = 7.5
[[fault]]
at_s = 4.0
rotor = 4
[plant]
mass_scale = 1.1
thrust_max_n = 24.0
sensor_noise = true
esc_telemetry = false
battery = true
battery_charge = 0.4
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_a_full_scenario_is_read_with_defaults_and_faults_in_time_order(tmp_path):
    s = load_scenario(write(tmp_path, GOOD))
    assert s.start.ned_m == (1.0, 2.0, -3.0) and s.start.yaw_deg == 90.0
    assert s.mission.on_fault == "continue"
    assert s.mission.waypoints[0].speed_m_s == 2.0
    assert s.mission.land.at_s == 8.0 and s.mission.land.descent_speed_m_s == 0.5
    assert [(f.at_s, f.rotor, f.loss, f.kind, f.until_s) for f in s.faults] == [
        (4.0, 4, 1.0, FaultKind.DEGRADED, None), (6.0, 2, 0.5, FaultKind.DAMAGE, 7.5)]
    assert s.plant.mass_scale == 1.1 and s.plant.inertia_scale == 1.0
    assert s.plant.thrust_max_n == 24.0 and s.plant.sensor_noise is True
    assert s.plant.esc_telemetry is False and s.plant.battery is True and s.plant.battery_charge == 0.4


@pytest.mark.parametrize("old,new,message", [
    ("rotor = 2", "rotor = 5", "rotor must be <= 4"),
    ("loss = 0.5", "loss = 1.5", "loss must be <= 1"),
    ("mass_scale = 1.1", "mass_scale = 1.1\nmas_scale = 2", "[plant]: unknown key(s) mas_scale"),
    ('on_fault = "continue"', 'on_fault = "panic"', "on_fault must be one of hold, continue"),
    ("ned_m = [5.0, 0.0, -3.0]", "ned_m = [5.0, 0.0, 3.0]", "z must be <= 0"),
    ("speed_m_s = 2.0", "speed_m_s = -2.0", "speed_m_s must be > 0"),
    ("at_s = 6.0", "at_s = 60.0", "at_s must be <= 10"),
    ("sensor_noise = true", 'sensor_noise = "yes"', "sensor_noise must be true or false"),
    ('name = "t"', "", "name is missing"),
    ('kind = "damage"', 'kind = "exploded"', "kind must be one of degraded, motor, propeller, damage"),
    ("until_s = 7.5", "until_s = 5.0", "until_s must be > 6"),
    ("until_s = 7.5", "until_s = 12.0", "until_s must be <= 10"),
    ("battery = true", "battery = 1", "battery must be true or false"),
])
def test_bad_scenarios_are_rejected_with_the_key_named(tmp_path, old, new, message):
    assert old in GOOD
    with pytest.raises(ConfigError) as err:
        load_scenario(write(tmp_path, GOOD.replace(old, new, 1)))
    assert message in str(err.value)


def test_malformed_toml_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_scenario(write(tmp_path, "name = [unclosed"))


def test_the_companion_reads_the_mission_alone_or_from_a_whole_scenario(tmp_path):
    whole = load_mission(write(tmp_path, GOOD))
    alone = load_mission(write(tmp_path, '[mission]\non_fault = "continue"\n[[mission.waypoint]]\n'
                                         'ned_m = [5.0, 0.0, -3.0]\nspeed_m_s = 2.0\nhold_s = 1.0\n'
                                         '[mission.land]\nat_s = 8.0\n', "m.toml"))
    assert whole == alone
    with pytest.raises(ConfigError, match="no \\[mission\\] table"):
        load_mission(write(tmp_path, 'name = "x"\n', "n.toml"))


@pytest.mark.parametrize("text, named", [
    (GOOD.replace('kind = "damage"', 'kind = "gremlins"'), r"\[\[fault\]\] #1 kind must be one of"),
    (GOOD.replace("rotor = 4", "rotor = 5"), r"\[\[fault\]\] #2 rotor must be <= 4"),
    (GOOD.replace("mass_scale = 1.1", "mass_scale = 1.1\nwind_m_s = 3.0"), r"\[plant\]: unknown key\(s\) wind_m_s"),
    (GOOD.replace("yaw_deg = 90.0", "yaw_deg = 900.0"), r"\[start\] yaw_deg must be <= 360"),
    (GOOD + "[sensors]\ngyro_noise = 0.1\n", r"\[sensors\]: unknown key\(s\) gyro_noise"),
    (GOOD + "[sensors]\nprofile = \"lidar\"\n", r"\[sensors\] profile must be one of ideal, mocap, gps"),
    (GOOD + "[sensors]\nprofile = 3\n", r"\[sensors\] profile must be"),
    ('[mission]\non_fault = "hold"\n[[fault]]\nat_s = 1.0\nrotor = 2\n', r"unknown key\(s\) fault \(a mission file"),
    ('[mission]\non_fault = "hold"\n[misson.land]\nat_s = 1.0\n', r"unknown key\(s\) misson"),
])
def test_a_mission_file_is_checked_whole_a_scenario_by_the_scenario_rules(tmp_path, text, named):
    with pytest.raises(ConfigError, match=named):
        load_mission(write(tmp_path, text, "mission.toml"))


def test_every_builtin_scenario_is_valid_and_the_paper_experiments_are_there():
    names = builtin_names()
    assert {"model-matching", "forward-flight-fault", "waypoint-loe", "fault-free"} <= set(names)
    for n in names:
        assert resolve(n).name == n
    wp = resolve("waypoint-loe")
    assert [(f.at_s, f.loss) for f in wp.faults] == [(7.0, 0.33), (14.0, 0.66), (21.0, 1.0)]
    assert resolve("forward-flight-fault").mission.waypoints[0].speed_m_s > 3.0


def test_unknown_scenario_name_lists_the_builtins():
    with pytest.raises(ConfigError, match="unknown scenario 'nope'.*model-matching"):
        scenario_path("nope")
