"""The session log: one SQLite file (WAL) and the images beside it, and what is read back from it.

`sessions` holds `SessionStore` (and re-exports the names of `schema` and `records`); `schema` the
file's schema and migrations, `owner` which console is alive, `steps` what each step of a run did,
`journal` a run's records that met a locked database, `records` the frozen records handed back,
`stats` predicted risk against what happened. Nothing here imports the rest of the console.
"""
