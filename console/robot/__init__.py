"""The robot drivers: what executes an approved plan step by step and reports what really happened.

`base` holds what every driver shares (events, outcomes, the step history, spec options);
`drivers` the simulated robot and `open_robot`; `tcp` the driver of `shelfpick.robot/1`. Nothing
here imports the workflow, the store or the web page.
"""
