"""Files at the boundary of the library: image files in (decoded, grey, streamed) and out, video files in (streamed
frames with their index and timestamp) and their timestamps tables, JSON and text written atomically, board sizes as
users write them.

Below the pipeline (which reads images through it) and free of the stages.
"""
