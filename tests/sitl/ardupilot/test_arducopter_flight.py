"""Flights through the real ArduCopter SITL (ARDUPILOT_SITL, else ../shared/ardupilot/arducopter
beside the repository) on the MuJoCo plant: ArduCopter's own controller, then the companion
through the M4 applet, each with a rotor loss; in the second, MAVProxy is a ground station on
ArduPilot's SERIAL2 (one arducopter boot for both)."""

from __future__ import annotations

import os

import pytest

from sitl import scenarios
from sitl.ardupilot.flight import ArduFlightOptions, fly_ardupilot, free_instance, sitl_binary
from sitl.plant.truth import load_truth
from tests.support.mavproxy_console import MavProxy

# the companion on the wall clock, in SCHED_FIFO against a busy machine where allowed (root)
REAL_TIME_PRIORITY = 50 if os.geteuid() == 0 else 0
SERIAL2_PORT = 5763                 # arducopter's SERIAL2: tcp 5763 + 10 x instance (SERIAL1 is the companion's)

pytestmark = [pytest.mark.ardupilot, pytest.mark.flight,
              pytest.mark.skipif(not sitl_binary().is_file(),
                                 reason=f"no ArduCopter SITL at {sitl_binary()} (set ARDUPILOT_SITL)")]


def test_arducopter_hovers_the_m4_and_the_rotor_loss_reaches_the_plant(tmp_path):
    scenario = scenarios.resolve("hover-rotor-loss")
    metrics = fly_ardupilot(ArduFlightOptions(scenario=scenario, out_dir=tmp_path, speedup=50.0, instance=free_instance(),
                                              timeout_s=240.0), log=lambda _: None)
    hover = metrics["hover"]
    assert hover["altitude_error_max_m"] < 0.3 and hover["tilt_max_deg"] < 5.0
    assert hover["horizontal_drift_max_m"] < 0.5
    truth = load_truth(tmp_path / "truth.npz")
    t = truth.time_s - metrics["scenario_t0_physics_s"]
    failed = t >= scenario.faults[0].at_s + 0.2
    assert (truth.thrust_n[failed, 3] < 1e-3).all()            # rotor 4 stopped: the fault went through the JSON path
    assert metrics["after_fault"]["tilt_max_deg"] > 30.0        # ArduCopter's quad mixer cannot hold three rotors
    assert (tmp_path / "flight.png").stat().st_size > 0


def test_the_companion_flies_the_hover_rotor_loss_through_arducopter_and_a_ground_station_runs_it(tmp_path):
    """One command end to end: the companion, arducopter with the applet, the physics; the
    companion takes over in the air, names the lost rotor, and the robot holds the air. MAVProxy
    on ArduPilot's SERIAL2, as a ground station beside the flight's own link, reads the applet's
    parameter, selects GUIDED and arms, and prints the companion's fault announcement."""
    scenario = scenarios.resolve("hover-rotor-loss")
    instance = free_instance()
    console: dict[str, MavProxy] = {}
    done: dict[str, bool] = {}

    def ground_station() -> None:
        gcs = console["gcs"] = MavProxy(f"tcp:127.0.0.1:{SERIAL2_PORT + 10 * instance}", tmp_path,
                                        modules="link,mode,arm,param")
        done["online"] = gcs.wait_for("online system 1", 30.0)
        gcs.command("param fetch M4_ENABLE")
        done["param"] = gcs.wait_for("M4_ENABLE = 0.0", 30.0)
        gcs.command("mode GUIDED")
        done["mode"] = gcs.wait_for("GUIDED>", 15.0)
        gcs.command("arm throttle")
        done["armed"] = gcs.wait_for("ARMED", 15.0)

    try:
        metrics = fly_ardupilot(ArduFlightOptions(scenario=scenario, out_dir=tmp_path, speedup=10.0, instance=instance,
                                                  timeout_s=400.0, companion=True, before_arming=ground_station,
                                                  priority=REAL_TIME_PRIORITY,
                                                  scenario_file=scenarios.scenario_path("hover-rotor-loss")),
                                log=lambda _: None)
        announced = console["gcs"].wait_for("AP: thrust loss rotor 4", 5.0)
    finally:
        printed = console["gcs"].close() if "gcs" in console else "(MAVProxy never started)"
    assert done == {"online": True, "param": True, "mode": True, "armed": True}, printed
    assert announced, printed                               # the companion's text, said again by the applet
    said = (tmp_path / "statustext.txt").read_text()
    assert "m4: flying companion setpoints" in said
    assert "thrust loss rotor 4" in metrics["after_fault"]["ardupilot_said"]   # the companion's, through ArduPilot
    assert metrics["after_fault"]["hit_the_floor_after_s"] is None
    truth = load_truth(tmp_path / "truth.npz")
    t = truth.time_s - metrics["scenario_t0_physics_s"]
    after = t > scenario.faults[0].at_s + 1.0
    assert (truth.hip_rad[after, 0] > 1.2).all() and (truth.hip_rad[after, 1] < 0.35).all()   # the legs moved the CoM
