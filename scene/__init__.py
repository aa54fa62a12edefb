"""The 3D scene: one process owning the `viser.ViserServer` (bound to 127.0.0.1 and open only to the app's
proxy, `backend/pages.py`), showing the robot moving in simulation, its camera view, the embedding sphere of
the household's clips and snapshots, the live reward, and the active model carrying out a chosen command.
Each household has its own scene process: the app starts it when a member opens the Scene page
(`on_demand`), and it stops once nobody has watched it for a while. `varbot scene --household <id>` starts one
by hand.

`service` runs the loop and wires the parts: `panel` (the controls and status line), `world_view` and `world`
(the simulated world and how the 3D view mirrors it), `sphere` (points, colours, markers, the reward),
`active_model` and `brain` (the household's VAR and policy), `refresh` and `household` (its data, re-read in
the background), `following` and `live` (a training run's rollouts), `trial` (trying a command), and `access`
and `endpoint` (who may connect, and how the app finds each household's scene), and `on_demand` (starting
a household's scene when asked, once however many API processes ask)."""
