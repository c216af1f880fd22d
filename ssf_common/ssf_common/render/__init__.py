"""Bird's-eye pictures and animations of an episode, from its recording or from frames held in memory.

`frames` holds the typed frame a picture is drawn from (`ViewFrame`, everything in the world frame) and the
episode read back from a recording (`EpisodeTrack`, `recording_frames`); `draw` turns frames into pixels with
matplotlib; `video` writes MP4 (imageio-ffmpeg) or GIF (Pillow) and the episode picture; `command` is `ssf render`. No simulator import: a
recording of any run (simulated or replayed) is enough.
"""
