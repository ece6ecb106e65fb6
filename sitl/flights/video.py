"""A flight on film: MuJoCo renders the plant's true state offscreen, after the flight.

    python -m sitl.flights.video FLIGHT_DIR [--width 640 --height 360 --fps 30]

reads FLIGHT_DIR/truth.npz (and metrics.json for the fault marks) and writes flight.mp4 (H.264,
real time: one frame every 1/fps s of simulated time, a chase camera following the hull at
a fixed bearing) and snapshots_render.png (the posture at eight instants around the first
fault, in one image, as the paper's sequential snapshots). A failing thruster turns red as
its true ceiling falls. The loop is long over when this runs: lockstep timing is untouched.

MuJoCo picks its OpenGL back end when it is first imported, so `make_video` renders in a
child process: with MUJOCO_GL=egl, then osmesa if EGL cannot (or as MUJOCO_GL says, if set).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe, load_airframe
from m4.attitude import quat_wxyz_from_euler
from sitl.plant import frames
from sitl.plant.mjcf import compile_model
from sitl.plant.truth import Truth, load_truth

VIDEO_FILE = "flight.mp4"
SNAPSHOTS_FILE = "snapshots_render.png"
GL_BACKENDS = ("egl", "osmesa")
SNAPSHOT_OFFSETS_S = (-0.5, 0.0, 0.1, 0.2, 0.35, 0.6, 1.0, 2.0)   # from the first fault
FAULT_RGBA = np.array([0.9, 0.05, 0.05, 1.0])
# Healthy discs by spin as seen from above: ccw light grey, cw blue (the model's own orange
# would be hard to tell from a failing rotor's red).
SPIN_RGBA = {1: (0.8, 0.8, 0.78, 0.9), -1: (0.15, 0.4, 0.85, 0.9)}
CRF = 28                                                          # x264 quality: small files, clean edges


class VideoError(RuntimeError):
    """The video could not be made (one line, for the user)."""


@dataclass(frozen=True)
class VideoOptions:
    width: int = 640
    height: int = 360
    fps: float = 30.0
    camera_distance_m: float = 1.5
    camera_azimuth_deg: float = -135.0
    camera_elevation_deg: float = -25.0


def frame_times_s(truth: Truth, fps: float) -> np.ndarray:
    """Simulated instants of the frames: from the first sample, 1/fps apart, to the last."""
    t0, t1 = float(truth.time_s[0]), float(truth.time_s[-1])
    return t0 + np.arange(int(np.floor((t1 - t0) * fps + 1e-9)) + 1) / fps


class PoseRenderer:
    """The plant's model posed from truth samples and rendered from a chase camera."""

    def __init__(self, af: Airframe, truth: Truth, width: int, height: int, options: VideoOptions):
        self.truth = truth
        self.af = af
        self.model = compile_model(af)
        self.data = mujoco.MjData(self.model)
        self.renderer = mujoco.Renderer(self.model, height, width)
        root = self.model.joint("root")
        self._root = int(self.model.jnt_qposadr[root.id])
        self._hips = [int(self.model.jnt_qposadr[self.model.joint(f"sagittal{i + 1}").id]) for i in range(ROTOR_COUNT)]
        # The thruster's visual disc: the wheel body's geom that is not the collision cylinder.
        self._discs = [next(g for g in range(self.model.ngeom) if self.model.geom_bodyid[g] == self.model.body(f"wheel{i + 1}").id
                            and self.model.geom(g).name != f"wheel{i + 1}") for i in range(ROTOR_COUNT)]
        self._disc_rgba = np.array([SPIN_RGBA[s] for s in af.spin_sign])
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.camera.distance = options.camera_distance_m
        self.camera.azimuth = options.camera_azimuth_deg
        self.camera.elevation = options.camera_elevation_deg

    def render(self, t_s: float) -> np.ndarray:
        """(height, width, 3) uint8 image of the sample nearest t_s."""
        t = self.truth
        k = int(np.clip(np.searchsorted(t.time_s, t_s - 1e-9), 0, len(t.time_s) - 1))
        qpos = self.data.qpos
        qpos[self._root:self._root + 3] = frames.flip_vector(t.pos_ned_m[k])
        qpos[self._root + 3:self._root + 7] = frames.flip_quat_wxyz(quat_wxyz_from_euler(t.euler_rad[k]))
        qpos[self._hips] = t.hip_rad[k]
        mujoco.mj_kinematics(self.model, self.data)
        loss = np.clip(1.0 - t.thrust_limit_n[k] / self.af.thrust_max_n, 0.0, 1.0)[:, None]
        self.model.geom_rgba[self._discs] = (1 - loss) * self._disc_rgba + loss * FAULT_RGBA
        self.camera.lookat[:] = qpos[self._root:self._root + 3]
        self.renderer.update_scene(self.data, self.camera)
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False   # 3x slower in software GL
        return self.renderer.render()


def captions(metrics: dict, t_s: float) -> list[tuple[str, str]]:
    """(text, colour) lines for the instant t_s: the flight and time, then each fault so far."""
    lines = [(f"{metrics.get('scenario', '')} ({metrics.get('controller', '')})   t = {t_s:5.2f} s", "white")]
    for fault in metrics.get("faults", []):
        if t_s >= fault["at_s"]:
            lines.append((f"rotor {fault['rotor']} lost {fault['loss']:.0%} of its thrust at {fault['at_s']:g} s", "#ff5050"))
        detected = fault.get("detected_at_s")
        if detected is not None and t_s >= detected:
            lines.append((f"detected rotor {fault['detected_rotor']} after {detected - fault['at_s']:.2f} s", "#ffd166"))
    return lines


def _annotate(image: np.ndarray, lines: list[tuple[str, str]], size: int) -> np.ndarray:
    from PIL import Image, ImageDraw, ImageFont

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=size)
    for i, (text, colour) in enumerate(lines):
        draw.text((8, 6 + i * (size + 4)), text, fill=colour, font=font, stroke_width=2, stroke_fill="black")
    return np.asarray(picture)


def render_video(flight_dir: Path, options: VideoOptions) -> int:
    """flight.mp4 of the flight in flight_dir; returns the number of frames."""
    import imageio_ffmpeg

    truth, metrics = load_truth(flight_dir / "truth.npz"), _metrics(flight_dir)
    poser = PoseRenderer(load_airframe(), truth, options.width, options.height, options)
    times = frame_times_s(truth, options.fps)
    writer = imageio_ffmpeg.write_frames(
        str(flight_dir / VIDEO_FILE), (options.width, options.height), fps=options.fps, codec="libx264",
        pix_fmt_out="yuv420p", macro_block_size=2, quality=None,
        output_params=["-crf", str(CRF), "-preset", "slow", "-movflags", "+faststart"])
    writer.send(None)
    text_size = max(10, options.height // 24)
    for t_s in times:
        writer.send(np.ascontiguousarray(_annotate(poser.render(t_s), captions(metrics, t_s), text_size)))
    writer.close()
    return len(times)


def snapshot_times_s(truth: Truth, metrics: dict) -> list[float]:
    """Eight instants: around the first fault if there is one, else spread over the flight."""
    t0, t1 = float(truth.time_s[0]), float(truth.time_s[-1])
    faults = metrics.get("faults") or []
    if not faults:
        return list(np.linspace(t0, t1, len(SNAPSHOT_OFFSETS_S)))
    return [float(np.clip(faults[0]["at_s"] + dt, t0, t1)) for dt in SNAPSHOT_OFFSETS_S]


def render_snapshots(flight_dir: Path, options: VideoOptions, columns: int = 4) -> Path:
    """snapshots_render.png: the posture at snapshot_times_s, in a grid, each tile labelled."""
    from PIL import Image

    truth, metrics = load_truth(flight_dir / "truth.npz"), _metrics(flight_dir)
    times = snapshot_times_s(truth, metrics)
    tile_w, tile_h = options.width // 2, options.height // 2 * 3 // 2
    poser = PoseRenderer(load_airframe(), truth, tile_w, tile_h, VideoOptions(camera_elevation_deg=-35.0))
    rows = -(-len(times) // columns)
    sheet = Image.new("RGB", (columns * tile_w, rows * tile_h), "white")
    for i, t_s in enumerate(times):
        lines = [(f"t = {t_s:.2f} s", "white")] + [line for line in captions(metrics, t_s)[1:] if "lost" in line[0]]
        tile = _annotate(poser.render(t_s), lines, max(10, tile_h // 14))
        sheet.paste(Image.fromarray(tile), ((i % columns) * tile_w, (i // columns) * tile_h))
    path = flight_dir / SNAPSHOTS_FILE
    sheet.save(path)
    return path


def _metrics(flight_dir: Path) -> dict:
    path = flight_dir / "metrics.json"
    return json.loads(path.read_text()) if path.exists() else {}


def make_video(flight_dir: str | Path, options: VideoOptions = VideoOptions()) -> tuple[Path, Path]:
    """Render flight.mp4 and snapshots_render.png of a flown flight's folder in a child process,
    trying each OpenGL back end in turn; raises VideoError saying why none worked."""
    flight_dir = Path(flight_dir)
    if not (flight_dir / "truth.npz").is_file():
        raise VideoError(f"{flight_dir}: no truth.npz to render (fly the scenario first)")
    backends = [os.environ["MUJOCO_GL"]] if os.environ.get("MUJOCO_GL") else list(GL_BACKENDS)
    reasons = []
    for backend in backends:
        cmd = [sys.executable, "-m", "sitl.flights.video", str(flight_dir), "--width", str(options.width),
               "--height", str(options.height), "--fps", f"{options.fps:g}"]
        done = subprocess.run(cmd, env={**os.environ, "MUJOCO_GL": backend}, capture_output=True, text=True)
        if done.returncode == 0:
            return flight_dir / VIDEO_FILE, flight_dir / SNAPSHOTS_FILE
        last = [ln for ln in done.stderr.splitlines() if ln.strip()]
        reasons.append(f"{backend}: {last[-1] if last else f'exit code {done.returncode}'}")
    raise VideoError("MuJoCo could not render offscreen (" + "; ".join(reasons)
                     + "); scripts/install.sh installs the EGL and OSMesa libraries")


def _even_size(text: str) -> int:
    value = int(text)
    if value < 16 or value % 2:
        raise argparse.ArgumentTypeError(f"must be an even number of pixels >= 16, got {text}")
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sitl.flights.video", description=__doc__.splitlines()[0])
    parser.add_argument("flight_dir", type=Path, help="a flight's folder (m4-sitl fly --out)")
    parser.add_argument("--width", type=_even_size, default=VideoOptions.width)
    parser.add_argument("--height", type=_even_size, default=VideoOptions.height)
    parser.add_argument("--fps", type=float, default=VideoOptions.fps)
    args = parser.parse_args(argv)
    options = VideoOptions(width=args.width, height=args.height, fps=args.fps)
    frames_written = render_video(args.flight_dir, options)
    render_snapshots(args.flight_dir, options)
    print(f"{args.flight_dir / VIDEO_FILE}: {frames_written} frames, {options.width}x{options.height} "
          f"at {options.fps:g} fps; {args.flight_dir / SNAPSHOTS_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
