"""The console's state machine: capture -> plan -> approve/reject -> execute -> stop, with no viser.

`machine` holds `Workflow`, composed of one module per stage (`planning_stage`, `supervision` with
its passphrase brake `throttle`, `run` the robot run, `look` and `verify` after each step,
`continuation` after a held step) over `core` (one lock over one `State`) and `state` (the
records); `run_json` is the JSON it stores. It drives `console/robot/` and records in `console/store/`.
"""
