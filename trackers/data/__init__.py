"""Data: frame sources (MOT folder, video file, image folder, synthetic scene) and MOT text I/O."""
