"""A web viewer of a run (viser): the cameras with their photos, the SfM points, and renders from the browser's camera.

`camera` turns the browser's camera into rays, `modes` renders what the user picked (RGB, depths, masks), `progressive`
refines a render while the camera rests, `scene` draws the cameras and points, `server` ties them to a viser server,
`simplenerf.commands.view` is `simplenerf view RUN`, `simplenerf.run.callbacks.viewer` is `fit --viewer true`.
docs/viewer.md is the user's guide.
"""
