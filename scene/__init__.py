"""The 3D scene: one process owning the `viser.ViserServer` (bound to 127.0.0.1), showing the robot moving in
simulation, its camera view, the embedding sphere of the household's clips and snapshots, the live reward,
and the active model carrying out a chosen command. The browser reaches it only through the app
(`backend/pages.py`). Start it with `varbot scene`."""
