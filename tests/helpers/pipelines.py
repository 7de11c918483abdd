"""Pipeline files for the tests."""

#: A tiny synthetic pipeline (4 cameras at 320x256, 3 frames): every stage in seconds.
TINY = """
name = "tiny"
capture = "cap"
work = "work"

[synth]
preset = "tiny4"
frames = 3
points_per_part = 40

[semantics]
recognizer = "simulated"
options = { noise = "low" }

[affinity]
tau = 0.02

[render]
size = [320, 256]
tail = 2

[executor]
workers = 1
"""
