"""Measuring perception: accuracy on rendered scenes against their ground truth and on real captures.

`bench` runs the measurements (`shelfpick perceive-bench`, scripts in benchmarks/), `scenes` samples
the seeded shelves they render and `truth` gives each rendered frame's true front-face masks. The
runtime in `perception/` never imports this package; training does (its frames are these renders).
"""
