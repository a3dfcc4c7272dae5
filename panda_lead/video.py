"""Render recorded episodes (``rollout.Rollout``) to an MP4: one panel per controller, side by side.

Videos are drawn from rollouts, not from a live env: an episode is played first (physics is
~1 ms a step, rendering ~100 ms a frame), then every panel is rendered in one pass through one
``mujoco.Renderer`` and one ``MjData``, and each frame goes straight to ffmpeg. A rollout holds
all it takes (joint angles, target, tip, lead at every 100 Hz step), so a saved rollout file
can be filmed too, and nothing here depends on how the env steps.

What a panel shows: the arm and the target (red ball) from a free camera fitted to the arm and
both paths; the target's last second (red trail) and the tip's (blue); the lead as a yellow
arrow from the target the IK used to the point it aimed at (yellow ball); the controller, the
time, and the tracking error now and averaged so far, in cm.

    from . import video
    video.write("out.mp4", [rollout_a, rollout_b], model)   # model: the scene's MjModel

A failed write (full disk, ffmpeg error, Ctrl-C) raises ``errors.UserError`` with one line and
leaves whatever was at the path before untouched (``atomicio.atomic_write``).
"""

from __future__ import annotations

import collections
import math
import subprocess
import sys
import threading
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import mujoco
import numpy as np

from .atomicio import atomic_write
from .errors import UserError


@dataclass(frozen=True)
class VideoConfig:
    width: int = 640
    """Width of one panel in pixels (a comparison is two panels wide)."""
    height: int = 480
    """Height in pixels."""
    fps: int = 50
    """Frames per second; 100 Hz control divided by a whole number (every 2nd step at 50)."""
    trail_s: float = 1.0
    """Seconds of the target's and the tip's past path drawn behind them."""
    shadows: bool = False
    """Cast shadows. In a software renderer (llvmpipe, headless EGL) they cost more than the
    rest of the frame (~0.2 s of ~0.3 s at 640x480, any shadow map size); the trails already
    show depth."""
    samples: int = 0
    """Multisampling of the offscreen buffer (the scene asks for 4). In a software renderer
    4x costs ~2.5x the frame time; at 640x480 the edges look nearly the same."""
    crf: int = 20
    """x264 quality (lower is better and larger; 18-23 is visually clean)."""


# --- labels ---------------------------------------------------------------------------------

def describe(meta: dict) -> str:
    """What drove an episode, from the rollout's meta, so a panel is never labelled by guess
    (with EnvConfig.follow_plan, the plan has the arm on a followable episode: said too)."""
    hand = " + plan" if (meta.get("env") or {}).get("follow_plan") else ""
    return _controller(meta) + hand


def _controller(meta: dict) -> str:
    name = meta.get("controller", "?")
    if name == "classical":
        return "classical IK+PD (no lead)"
    if name == "analytic":
        tau = meta.get("tau")
        return f"analytic lead, tau {tau:.2f} s" if tau is not None else "analytic lead"
    if name == "policy":
        model = meta.get("model")
        return f"policy lead ({Path(model).stem})" if model else "policy lead"
    return str(name)


@cache
def font(size: int, bold: bool = False):
    """DejaVu Sans from matplotlib's bundled fonts (always installed with it): legible, unlike
    PIL's default bitmap font; PIL's scalable default font if matplotlib is missing."""
    from PIL import ImageFont

    name = "DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"
    try:
        import matplotlib

        return ImageFont.truetype(str(Path(matplotlib.get_data_path()) / "fonts" / "ttf" / name),
                                  size)
    except (ImportError, OSError):
        return ImageFont.load_default(size)


# --- camera ---------------------------------------------------------------------------------

def _forward(azimuth: float, elevation: float) -> np.ndarray:
    """Viewing direction of a free camera (MuJoCo's convention, degrees)."""
    a, e = math.radians(azimuth), math.radians(elevation)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def _camera_axes(forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return right, np.cross(right, forward)


def _best_azimuth(path: np.ndarray, elevation: float) -> float:
    """The azimuth from which the target's path looks widest (a circle seen edge-on hides any
    lag), among views from in front of the arm and to one side: the camera's direction is
    100-150 deg from the arm's reach (base to path), so the hand does not sit on the target."""
    reach = math.degrees(math.atan2(path[:, 1].mean(), path[:, 0].mean()))
    best, best_score = 150.0, -1.0
    for az in np.arange(0.0, 360.0, 5.0):
        off = abs((az - reach + 180.0) % 360.0 - 180.0)
        if not 100.0 <= off <= 150.0:
            continue
        right, up = _camera_axes(_forward(az, elevation))
        flat = (path - path.mean(0)) @ np.stack([right, up], 1)
        score = np.linalg.eigvalsh(np.cov(flat.T))[0]  # the narrower spread of the two
        if score > best_score + 1e-6:
            best, best_score = float(az), score
    return best


def arm_points(model: mujoco.MjModel, qpos: np.ndarray, stride: int = 10) -> np.ndarray:
    """Positions of every body of the arm over an episode (every ``stride``-th row)."""
    data = mujoco.MjData(model)
    pts = []
    for q in qpos[::stride]:
        data.qpos[:len(q)] = q
        mujoco.mj_kinematics(model, data)
        pts.append(data.xpos[1:].copy())  # body 0 is the world
    return np.concatenate(pts)


def fit_camera(model: mujoco.MjModel, rollouts, aspect: float,
               elevation: float = -20.0, margin: float = 0.08) -> mujoco.MjvCamera:
    """A free camera that frames the arm and both paths of every rollout, as large as fits.

    ``margin`` (m) pads every point: bodies are points at their frames, the links are ~0.1 m
    thick. The distance is the smallest at which each padded point is inside both fields of
    view (vertical from the model, horizontal from the aspect ratio)."""
    paths = np.concatenate([r.target_pos for r in rollouts])
    pts = np.concatenate([paths, *[r.ee_pos for r in rollouts],
                          *[arm_points(model, r.qpos) for r in rollouts]])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.elevation = elevation
    cam.azimuth = _best_azimuth(paths[np.all(np.isfinite(paths), axis=1)], elevation)
    cam.lookat[:] = (pts.min(0) + pts.max(0)) / 2
    f = _forward(cam.azimuth, elevation)
    right, up = _camera_axes(f)
    rel = pts - cam.lookat
    tan_y = math.tan(math.radians(model.vis.global_.fovy) / 2)
    need_x = (np.abs(rel @ right) + margin) / (tan_y * aspect)
    need_y = (np.abs(rel @ up) + margin) / tan_y
    # A point at depth along f is seen at distance + depth: subtract it from what it needs.
    cam.distance = float(np.max(np.maximum(need_x, need_y) - rel @ f))
    return cam


# --- 3-D markers ----------------------------------------------------------------------------

TARGET_TRAIL = np.array([1.0, 0.35, 0.3, 0.8], dtype=np.float32)
TIP_TRAIL = np.array([0.25, 0.6, 1.0, 0.8], dtype=np.float32)
LEAD = np.array([1.0, 0.85, 0.1, 1.0], dtype=np.float32)


def _add(scene: mujoco.MjvScene, kind, rgba, size=(0.0, 0.0, 0.0), pos=(0.0, 0.0, 0.0)):
    """Append one decoration geom to the scene (None when the scene is full)."""
    if scene.ngeom >= scene.maxgeom:
        return None
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, kind, np.asarray(size, float), np.asarray(pos, float),
                        np.eye(3).ravel(), rgba)
    scene.ngeom += 1
    return g


def _segment(scene, kind, a, b, width, rgba) -> None:
    g = _add(scene, kind, rgba)
    if g is not None:
        mujoco.mjv_connector(g, kind, width, np.asarray(a, float), np.asarray(b, float))


def _trail(scene, points: np.ndarray, rgba: np.ndarray, width: float) -> None:
    """A path as lines ``width`` pixels wide, fading out towards its oldest end. Lines, not
    capsules: a hundred shaded capsules cost a software renderer as much as the arm."""
    n = len(points) - 1
    for i in range(n):
        faded = rgba.copy()
        faded[3] *= (i + 1) / n
        _segment(scene, mujoco.mjtGeom.mjGEOM_LINE, points[i], points[i + 1], width, faded)


def draw_markers(scene: mujoco.MjvScene, rollout, k: int, trail_rows: int) -> None:
    """Trails up to row k, and the lead of step k: the IK aimed at the target of the step's
    start (the previous row's target, or the path's start) plus the lead."""
    lo = max(0, k - trail_rows)
    step = 2  # a segment every 20 ms: smooth at these speeds, half the geoms
    _trail(scene, rollout.target_pos[lo:k + 1][::-1][::step][::-1], TARGET_TRAIL, 4)
    _trail(scene, rollout.ee_pos[lo:k + 1][::-1][::step][::-1], TIP_TRAIL, 4)
    base = rollout.target_pos[max(k - 1, 0)]
    aim = np.asarray(base) + rollout.lead[k]
    if np.linalg.norm(rollout.lead[k]) > 0.005:  # an arrow shorter than its head is noise
        _segment(scene, mujoco.mjtGeom.mjGEOM_ARROW, base, aim, 0.01, LEAD)
    _add(scene, mujoco.mjtGeom.mjGEOM_SPHERE, LEAD, size=(0.014, 0, 0), pos=aim)


# --- 2-D overlay ----------------------------------------------------------------------------

def _shade(frame: np.ndarray, box: tuple[int, int, int, int]) -> None:
    """Darken a box so white text on it reads over a bright floor or sky."""
    x0, y0, x1, y1 = box
    frame[y0:y1, x0:x1] = frame[y0:y1, x0:x1] // 3


def _fitting(draw, text: str, room: float, size: int):
    """The largest bold font, from `size` down to 60% of it, whose `text` fits in `room` px: a
    long model name in a side-by-side title must not run into the clock."""
    for px in range(size, max(round(0.6 * size), 1) - 1, -1):
        f = font(px, True)
        if draw.textlength(text, font=f) <= room:
            return f
    return f


def overlay(frame: np.ndarray, title: str, t: float, err_now: float, err_mean: float,
            note: str | None = None) -> np.ndarray:
    """Title top left, time top right, error along the bottom (cm), an optional red note."""
    from PIL import Image, ImageDraw

    h, w = frame.shape[:2]
    s = h / 480  # sizes are chosen at 480 px high and scale with the frame
    big, small = font(round(24 * s), True), font(round(20 * s))
    bar = round(38 * s)
    _shade(frame, (0, 0, w, bar))
    _shade(frame, (0, h - bar, w, h))
    img = Image.fromarray(frame)
    draw = ImageDraw.Draw(img)
    pad = round(8 * s)
    clock = f"t {t:4.2f} s"
    room = w - 4 * pad - draw.textlength(clock, font=big)
    draw.text((pad, pad), title, font=_fitting(draw, title, room, round(24 * s)),
              fill=(255, 255, 255))
    draw.text((w - pad, pad), clock, font=big, fill=(255, 255, 255), anchor="ra")
    draw.text((pad, h - bar + pad), f"error {100 * err_now:5.1f} cm   mean {100 * err_mean:5.1f} cm",
              font=small, fill=(255, 255, 255))
    legend = [("target", TARGET_TRAIL), ("tip", TIP_TRAIL), ("lead", LEAD)]
    x = w - pad
    for name, rgba in reversed(legend):
        draw.text((x, h - bar + pad), name, font=small, anchor="ra",
                  fill=tuple(int(255 * c) for c in rgba[:3]))
        x -= draw.textlength(name, font=small) + pad * 2
    if note:
        draw.text((w // 2, h // 2), note, font=big, anchor="mm", fill=(255, 60, 60),
                  stroke_width=2, stroke_fill=(0, 0, 0))
    return np.asarray(img)


# --- encoding -------------------------------------------------------------------------------

class FfmpegWriter:
    """Frames piped to ffmpeg (H.264, yuv420p: plays everywhere) as they are rendered.

    imageio's ffmpeg writer never looks at ffmpeg's exit status, so a full disk gave an
    unplayable file and no error; here ``close`` waits for ffmpeg and raises ``OSError`` with
    ffmpeg's own last words when it failed. Its stderr is drained by a thread into a short
    buffer (a full pipe would stall ffmpeg, and us with it)."""

    def __init__(self, path: str, width: int, height: int, fps: int, crf: int = 20):
        import imageio_ffmpeg

        cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-nostdin",
               "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}",
               "-r", str(fps), "-i", "-", "-c:v", "libx264", "-preset", "veryfast",
               "-crf", str(crf), "-pix_fmt", "yuv420p", "-f", "mp4", str(path)]
        self._size = (height, width, 3)
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        self._log: collections.deque[str] = collections.deque(maxlen=20)
        self._drain = threading.Thread(target=self._read_log, daemon=True)
        self._drain.start()

    def _read_log(self) -> None:
        for line in self._proc.stderr:
            self._log.append(line.decode(errors="replace").strip())

    def append(self, frame: np.ndarray) -> None:
        if frame.shape != self._size:
            raise ValueError(f"frame shape {frame.shape}, expected {self._size}")
        try:
            self._proc.stdin.write(np.ascontiguousarray(frame, dtype=np.uint8).tobytes())
        except BrokenPipeError:  # ffmpeg died: its exit status and message say why
            self.close()
            raise

    def close(self) -> None:
        if self._proc.stdin and not self._proc.stdin.closed:
            try:
                self._proc.stdin.close()
            except BrokenPipeError:
                pass
        code = self._proc.wait()
        self._drain.join()
        if code != 0:
            raise OSError(f"ffmpeg failed ({self._exit(code)}): {self.message()}")

    def kill(self) -> None:
        """Stop ffmpeg without waiting for a playable file (on Ctrl-C or an error)."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()

    def message(self) -> str:
        lines = [s for s in self._log if s]
        return lines[-1] if lines else "no message"

    @staticmethod
    def _exit(code: int) -> str:
        if code < 0:
            import signal

            return f"killed by {signal.Signals(-code).name}"
        return f"exit status {code}"


# --- the video ------------------------------------------------------------------------------

def frame_rows(n_rows: int, every: int) -> list[int]:
    """Rollout rows shown as frames: every ``every``-th step, the first one ``every`` steps in
    (a 0.3 s episode at 100 Hz gives 15 frames at 50 fps)."""
    return list(range(every - 1, n_rows, every))


def _renderer(model: mujoco.MjModel, config: VideoConfig) -> mujoco.Renderer:
    """One renderer for every panel and frame. Multisampling is read once, when the GL
    context is made, so it is set on the model just for that moment."""
    quality = model.vis.quality
    saved = quality.offsamples
    quality.offsamples = config.samples
    try:
        return mujoco.Renderer(model, config.height, config.width)
    finally:
        quality.offsamples = saved


def _scene_flags(scene: mujoco.MjvScene, config: VideoConfig) -> None:
    """Render switches, set after each update_scene. The floor's mirror image of the arm
    doubles the clutter and the render time."""
    scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
    scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = int(config.shadows)


class Panel:
    """One rollout, rendered one frame at a time with its running error."""

    def __init__(self, rollout, title: str | None = None):
        self.r = rollout
        self.title = title or describe(rollout.meta)
        err = np.linalg.norm(rollout.ee_pos - rollout.target_pos, axis=1)
        self.err = err
        self.err_mean = np.cumsum(err) / np.arange(1, len(err) + 1)

    def draw(self, renderer, model, data, camera, k: int, config: VideoConfig) -> np.ndarray:
        last = len(self.r.t) - 1
        note = None
        if k > last:  # this episode ended early: hold its last frame, say why
            k, note = last, f"ended: {self.r.meta.get('failure') or 'early'}"
        data.qpos[:self.r.qpos.shape[1]] = self.r.qpos[k]
        data.mocap_pos[0] = self.r.target_pos[k]
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera)
        _scene_flags(renderer.scene, config)
        draw_markers(renderer.scene, self.r, k, round(config.trail_s / self.r.dt))
        frame = renderer.render()
        return overlay(frame, self.title, float(self.r.t[k]), self.err[k], self.err_mean[k], note)


def _side_by_side(frames: list[np.ndarray]) -> np.ndarray:
    """Panels left to right, a dark 2 px rule between them so their labels do not run on."""
    out = np.concatenate(frames, axis=1)
    w = frames[0].shape[1]
    for i in range(1, len(frames)):
        out[:, i * w - 1:i * w + 1] = 0
    return out


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="frame", desc="rendering", file=sys.stderr, disable=not enabled,
                mininterval=1.0, dynamic_ncols=True)


def write(path, rollouts, model: mujoco.MjModel, titles=None, config: VideoConfig = VideoConfig(),
          progress: bool = True) -> None:
    """Render rollouts side by side to an MP4 at ``path``; see the module docstring."""
    path = Path(path)
    rows_per_s = round(1.0 / rollouts[0].dt)  # one rollout row per control step
    if rows_per_s % config.fps:
        raise ValueError(f"fps must divide the control rate {rows_per_s} Hz, got {config.fps}")
    titles = titles or [None] * len(rollouts)
    panels = [Panel(r, t) for r, t in zip(rollouts, titles, strict=True)]
    every = rows_per_s // config.fps
    rows = frame_rows(max(len(r.t) for r in rollouts), every)
    camera = fit_camera(model, rollouts, config.width / config.height)
    renderer = _renderer(model, config)
    data = mujoco.MjData(model)
    existed = path.exists()
    try:
        with atomic_write(path, ".tmp.mp4") as tmp:
            writer = FfmpegWriter(tmp, config.width * len(panels), config.height, config.fps,
                                  config.crf)
            try:
                with _progress(len(rows), progress) as bar:
                    for k in rows:
                        writer.append(_side_by_side(
                            [p.draw(renderer, model, data, camera, k, config) for p in panels]))
                        bar.update()
                writer.close()
            except BaseException:
                writer.kill()
                raise
    except OSError as exc:
        kept = "the old file is unchanged" if existed else "nothing was written"
        raise UserError(f"could not write {path}: {_reason(exc)}; {kept}") from exc
    finally:
        renderer.close()


def _reason(exc: OSError) -> str:
    """One line: errno text for a system error, the message for ffmpeg's."""
    if exc.strerror:
        return exc.strerror
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__
