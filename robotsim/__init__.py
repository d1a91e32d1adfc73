"""The robot side of the `shelfpick.robot/1` socket (docs/robot-protocol.md).

- `robotsim.wire`: what both ends of the socket speak: the protocol name,
  line-delimited JSON framing with its caps (`LineConn`) and its errors;
- `robotsim.transform`: the shelf-to-robot-base transform the grasp travels in;
- `robotsim.controller`: a reference robot-side server that acts on a
  simulated shelf (`python -m shelfpick.robotsim --port 9000`); the console's tests
  run against it.

The console's TCP driver (`console/robot/tcp.py`) imports `wire` and
`transform` from here; nothing here imports `console`, so the robot side can
be read, run and ported on its own.
"""
