"""The browser's side: the viser app, the parts of its page, and a stored session replayed.

`app` holds `ConsoleApp` (one `ClientView` per browser over one workflow); `panels` the page's
parts, `markdown` what the page says, `scene_view` the 3D shelf, `replay_view` a stored session
drawn in the page, `replay` one as a self-contained HTML file; `origin_guard` refuses foreign
origins. It reads `console/workflow/` and `console/store/`; nothing below imports it.
"""
