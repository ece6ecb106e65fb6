"""`m4-sitl fly SCENARIO`: one whole flight, then its metrics and figures.

`fly()` flies (sitl.flights.flight_run), reads the records back (sitl.flights.records, sitl.plant.truth), computes
metrics.json (sitl.flights.metrics) and draws the figures (sitl.flights.figures) into the flight's folder
(default runs/<scenario>-<UTC timestamp>). The model-matching scenario also gets the
open-loop comparison of the reduced-order model with the plant (sitl.flights.model_matching).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from tqdm import tqdm

from m4.airframe import Airframe, load_airframe
from m4.scenario import Scenario, load_scenario
from sitl import scenarios
from sitl.flights.flight_run import FlightFiles, FlightOptions, Start, run_flight, start_process
from sitl.flights.metrics import flight_metrics, reference_track
from sitl.flights.records import nmpc_log, read_fault_status, read_feed, setpoint_lead_ms
from sitl.plant.truth import load_truth

MODEL_MATCHING = "model-matching"
DEFAULT_OPTIONS = FlightOptions()      # frozen: safe as a shared default


def default_out_dir(name: str) -> Path:
    return Path("runs") / f"{name}-{time.strftime('%Y%m%d-%H%M%S', time.gmtime())}"


def fly(scenario_arg: str, out_dir: Path | None = None, options: FlightOptions = DEFAULT_OPTIONS,
        figures: bool = True, progress: bool = True, start: Start = start_process) -> dict:
    """Fly a built-in scenario or a scenario file; returns the metrics (also in metrics.json).
    A bad scenario raises ConfigError, a flight that cannot start FlightError. `start` starts the
    companion and the SITL (run_flight's)."""
    path = scenarios.scenario_path(scenario_arg)
    scenario = load_scenario(path)
    out_dir = Path(out_dir) if out_dir is not None else default_out_dir(scenario.name)
    # A progress bar in simulated seconds, on a terminal only (disable=None: off when not a TTY).
    with tqdm(total=scenario.duration_s, desc=f"fly {scenario.name}", unit="s", disable=None if progress else True,
              bar_format="{desc}: {bar} {n:.1f}/{total:g} s simulated [{elapsed}]") as bar:
        files = run_flight(scenario, path.read_text(), out_dir, options, lambda t_s: bar.update(t_s - bar.n), start)
    return evaluate(files, scenario, options.controller, load_airframe(), figures, options.link_conditions())


def evaluate(files: FlightFiles, scenario: Scenario, controller: str, af: Airframe, figures: bool = True,
             link: dict | None = None) -> dict:
    """metrics.json and the figures of a flown flight's folder; `link`: the link's conditions
    (FlightOptions.link_conditions), recorded with the setpoint lead the companion measured."""
    truth = load_truth(files.truth)
    fault_status = read_fault_status(files.tlog)
    ref = reference_track(scenario, af, truth, fault_status)
    feed = read_feed(files.feed)
    metrics = flight_metrics(scenario, controller, af, truth, ref, fault_status, nmpc_log(feed))
    metrics["link"] = {**(link or DEFAULT_OPTIONS.link_conditions()), "setpoint_lead_ms": setpoint_lead_ms(feed)}
    if scenario.name == MODEL_MATCHING:
        metrics["model_matching"] = _model_matching(files.out_dir, af, figures)
    files.metrics.write_text(json.dumps(metrics, indent=2) + "\n")
    if figures:
        from sitl.flights.figures import flight_figures

        flight_figures(files, f"{scenario.name} ({controller})", af, truth, metrics["faults"])
    return metrics


def _model_matching(out_dir: Path, af: Airframe, figures: bool) -> dict:
    from sitl.flights.model_matching import SUMMARY_HORIZONS_S, compare

    result = compare(af)
    if figures:
        from sitl.flights.figures import model_matching_figure

        model_matching_figure(out_dir / "model_matching.png", result)
    return {f"over_{t:g}_s": {k: round(v, 4) for k, v in result.errors_until(t).items()} for t in SUMMARY_HORIZONS_S}


def summary_line(metrics: dict, out_dir: Path) -> str:
    m = metrics
    verdict = "survived" if m["survived"] else "FAILED " + ", ".join(k for k, ok in m["checks"].items() if not ok)
    loss = m["altitude_loss_m"]
    return (f"{m['scenario']} ({m['controller']}): {verdict}; altitude loss {loss:.2f} m, max tilt "
            f"{m['max_tilt_deg_after_fault']:.1f} deg, position RMSE {m['position_rmse_m']:.2f} m, "
            f"{_link_text(m.get('link'))}{m['realtime_factor'] or 0:.1f}x real time -> {out_dir}")


def _link_text(link: dict | None) -> str:
    """The link's conditions and the measured lead, when the link was impaired."""
    if not link or link["mode"] == "none":
        return ""
    lead = link["setpoint_lead_ms"]
    return (f"link {link['delay_ms']:g} ms each way, loss {link['loss']:g} ({link['mode']}), setpoint lead "
            f"{'unmeasured' if lead is None else f'{lead:.0f} ms'}, ")
