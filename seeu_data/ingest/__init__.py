"""Ingest: a video or an image folder to posed frames. Frame decoding and selection (video,
frame_select), structure from motion (sfm, match_graph, keyframes), pose alignment (pose_eval), scale
and chunking (scale, chunks), SfM points kept for near/far (points), and the report (report). The stage
driver is pipelines/ingest.py."""
