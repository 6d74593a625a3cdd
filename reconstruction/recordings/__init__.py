"""Recordings of other eye-in-hand systems, read into one checked record (`Recording`).

recording     the records (RecordedView, Recording) and the checks every recording passes
idr           IDR / NeuS folders (cameras_sphere.npz; DTU MVS): P = K [R | t] split and checked
colmap_model  COLMAP sparse models, text and binary, read and written
colmap        COLMAP projects: the model's images with a stated metric scale
plain         the plain YAML form (recording.yaml)
formats       the format detected or named, and the one entry point read_recording
"""
