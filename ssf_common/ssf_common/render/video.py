"""Episode animations (MP4 through imageio-ffmpeg, GIF through Pillow) and the episode picture, from frames in
memory (`write_video`) or from a recording (`render_recording`)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np

from ssf_common.errors import ConfigError, DataError
from ssf_common.paths import check_writable
from ssf_common.render.frames import NS, RenderConfig, ViewFrame

VIDEO_SUFFIXES = (".mp4", ".gif")
OVERVIEW_VOXEL_M = 0.5  # the route overview keeps one static point per voxel
OVERVIEW_EVERY_S = 1.0  # and takes them from one scan per second
GIF_COLOURS = 96


def check_video_path(path: str | Path, what: str = "video") -> Path:
    """Refuse, in one line and before any work, a video path that cannot be written or encoded here."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise ConfigError(f"{what} {path}: the name must end in {' or '.join(VIDEO_SUFFIXES)}")
    if path.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ConfigError(f"{what} {path}: MP4 needs imageio-ffmpeg (pip install 'ssf-pan[video]'), "
                              "or write a .gif") from None
    return check_writable(path, what)


class VideoWriter:
    """Appends RGB frames of one size to an MP4 or a GIF file."""

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = check_video_path(path)
        self.fps = fps
        self.frames = 0
        self._mp4: Any = None
        self._gif: list[Any] = []

    def append(self, rgb: np.ndarray) -> None:
        """Add one (H, W, 3) uint8 frame."""
        if self.path.suffix.lower() == ".gif":
            from PIL import Image

            self._gif.append(Image.fromarray(rgb).quantize(colors=GIF_COLOURS, method=Image.Quantize.MEDIANCUT))
        else:
            if self._mp4 is None:
                import imageio_ffmpeg

                height, width = rgb.shape[:2]
                self._mp4 = imageio_ffmpeg.write_frames(str(self.path), (width, height), fps=self.fps,
                                                        codec="libx264", pix_fmt_out="yuv420p", quality=7,
                                                        macro_block_size=16, ffmpeg_log_level="error")
                self._mp4.send(None)
            self._mp4.send(np.ascontiguousarray(rgb))
        self.frames += 1

    def close(self) -> None:
        """Finish the file."""
        try:
            if self._mp4 is not None:
                self._mp4.close()
            elif self._gif:
                self._gif[0].save(self.path, save_all=True, append_images=self._gif[1:], loop=0, optimize=True,
                                  duration=int(round(1000 / self.fps)), disposal=1)
        except (OSError, RuntimeError) as err:
            raise DataError(f"{self.path}: cannot write the video ({err})") from None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_video(frames: Iterable[ViewFrame], path: str | Path, config: RenderConfig | None = None, *,
                title: str = "", start_ns: int | None = None, progress: IO[str] | None = None,
                total: int | None = None) -> int:
    """Animate frames (in time order, e.g. kept in memory by a navigation trial) into `path`, their times counted
    from `start_ns` (default: the first frame's); the frame count."""
    from ssf_common.render.draw import FrameDrawer

    config = config or RenderConfig()
    drawer: FrameDrawer | None = None
    with VideoWriter(path, config.fps) as writer:
        for frame in frames:
            if drawer is None:
                drawer = FrameDrawer(config, frame.stamp_ns if start_ns is None else start_ns, title)
            writer.append(drawer.draw(frame))
            _say_progress(progress, writer.frames, total)
    if drawer is not None:
        drawer.close()
    return writer.frames


class RenderSummary(NamedTuple):
    """What `render_recording` drew."""

    frames: int  # frames in the video (0 without one)
    seconds: float  # span of the recording drawn
    picture: Path | None
    video: Path | None


def render_recording(recording: str | Path, *, picture: str | Path | None = None, video: str | Path | None = None,
                     config: RenderConfig | None = None, title: str = "",
                     progress: IO[str] | None = None) -> RenderSummary:
    """Draw a recorded episode: the picture (route overview, last moment, fusion Δ, the perception scan by scan
    against the truth) and/or the animation."""
    from ssf_common.render.counts import judge_recording
    from ssf_common.render.draw import draw_episode_picture
    from ssf_common.render.frames import open_track, recording_frames, schedule

    config = config or RenderConfig()
    if video is not None:
        check_video_path(video, "video")
    if picture is not None:
        check_writable(picture, "episode picture")
    bag, track = open_track(recording)
    with bag:
        planned = schedule(track, config)
        if video is None:  # the picture alone needs one scan per second and the last one
            every = max(int(round(OVERVIEW_EVERY_S * config.fps / config.stride)), 1)
            planned = planned[::every] + planned[-1:] if planned else planned
        if not planned:
            raise DataError(f"{recording}: no scans to draw (no /lidar/points or /ssf/semantic_flow)")
        judged = judge_recording(bag, track, config)
        overview = OverviewMap(int(OVERVIEW_EVERY_S * NS))
        frames = _observed(recording_frames(bag, track, config, planned, judged), overview)
        title = title or _default_title(track, recording)
        count = 0
        if video is not None:
            start = int(track.truth.stamps[0]) if len(track.truth) else None
            count = write_video(frames, video, config, title=title, start_ns=start, progress=progress,
                                total=len(planned))
        else:
            for _ in frames:
                pass
        if overview.last is None:
            raise DataError(f"{recording}: no scan could be placed in the world (true poses missing)")
        if picture is not None:
            counts = [judged[stamp].counts for stamp in sorted(judged)]
            draw_episode_picture(picture, overview.last, overview.points(), track, config, title, counts)
    span = (overview.last.stamp_ns - planned[0].stamp_ns) / NS
    return RenderSummary(count, span, Path(picture) if picture else None, Path(video) if video else None)


def _default_title(track: Any, recording: str | Path) -> str:
    """`urban_100, seed 2, 100 agents: demo_20261204_182800` (the episode and the folder the recording is in)."""
    from ssf_common.render.draw import episode_name

    folder = Path(recording).resolve().parent.name
    return f"{episode_name(track)}: {folder}" if track.scenario else folder


class OverviewMap:
    """The static points of one scan per period, thinned to a voxel grid, and the last frame seen."""

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.last: ViewFrame | None = None
        self._next_ns: int | None = None
        self._chunks: list[np.ndarray] = []

    def add(self, frame: ViewFrame) -> None:
        """Remember the frame; take its static points when a period has passed."""
        self.last = frame
        if self._next_ns is not None and frame.stamp_ns < self._next_ns:
            return
        self._next_ns = frame.stamp_ns + self.period_ns
        static = frame.points if frame.labels is None else frame.points[frame.labels == 0]
        self._chunks.append(_thinned(static[:, :2]))

    def points(self) -> np.ndarray:
        """(N, 2) the thinned static points."""
        return _thinned(np.concatenate(self._chunks)) if self._chunks else np.zeros((0, 2), np.float32)


def _thinned(xy: np.ndarray) -> np.ndarray:
    from ssf_common.geometry.sampling import voxel_indices

    return xy[voxel_indices(xy, OVERVIEW_VOXEL_M)] if len(xy) else xy


def _observed(frames: Iterable[ViewFrame], overview: OverviewMap) -> Iterable[ViewFrame]:
    for frame in frames:
        overview.add(frame)
        yield frame


def _say_progress(progress: IO[str] | None, done: int, total: int | None) -> None:
    if progress is None or not total:
        return
    step = max(total // 10, 1)
    if done % step == 0 or done == total:
        print(f"render: {done}/{total} frames", file=progress, flush=True)


__all__ = ["RenderSummary", "VideoWriter", "check_video_path", "render_recording", "write_video"]
