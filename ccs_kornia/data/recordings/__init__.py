"""Rendered recordings of a hand-held board (docs/recordings.md): the recording and its truth (recordings), the camera
that records (recording_camera), the board's motion (handheld), one exposure with its rolling shutter and motion blur
(exposure), what the board shows (patterns) and the files on disk (recording_files).
"""
