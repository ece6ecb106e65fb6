"""Flights through the real ArduCopter SITL (ARDUPILOT_SITL, else ../shared/ardupilot/arducopter
beside the repository) on the MuJoCo plant: ArduCopter's own controller, then the companion
through the M4 applet, each with a rotor loss."""

from __future__ import annotations

import pytest

from sitl import scenarios
from sitl.ardupilot.flight import ArduFlightOptions, fly_ardupilot, sitl_binary
from sitl.plant.truth import load_truth

pytestmark = [pytest.mark.ardupilot, pytest.mark.flight,
              pytest.mark.skipif(not sitl_binary().is_file(),
                                 reason=f"no ArduCopter SITL at {sitl_binary()} (set ARDUPILOT_SITL)")]


def test_arducopter_hovers_the_m4_and_the_rotor_loss_reaches_the_plant(tmp_path):
    scenario = scenarios.resolve("hover-rotor-loss")
    metrics = fly_ardupilot(ArduFlightOptions(scenario=scenario, out_dir=tmp_path, speedup=50.0, instance=4,
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


def test_the_companion_flies_the_hover_rotor_loss_through_arducopter_and_the_m4_applet(tmp_path):
    """One command end to end: the companion, arducopter with the applet, the physics; the
    companion takes over in the air, names the lost rotor, and the robot holds the air."""
    scenario = scenarios.resolve("hover-rotor-loss")
    metrics = fly_ardupilot(ArduFlightOptions(scenario=scenario, out_dir=tmp_path, speedup=10.0, instance=5,
                                              timeout_s=400.0, companion=True,
                                              scenario_file=scenarios.scenario_path("hover-rotor-loss")),
                            log=lambda _: None)
    said = (tmp_path / "statustext.txt").read_text()
    assert "m4: flying companion setpoints" in said
    assert "thrust loss rotor 4" in metrics["after_fault"]["ardupilot_said"]   # the companion's, through ArduPilot
    assert metrics["after_fault"]["hit_the_floor_after_s"] is None
    truth = load_truth(tmp_path / "truth.npz")
    t = truth.time_s - metrics["scenario_t0_physics_s"]
    after = t > scenario.faults[0].at_s + 1.0
    assert (truth.hip_rad[after, 0] > 1.2).all() and (truth.hip_rad[after, 1] < 0.35).all()   # the legs moved the CoM
