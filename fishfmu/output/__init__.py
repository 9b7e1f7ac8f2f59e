"""What a run leaves on disk: atomic writes, the rules that keep a user's files safe (the output
folder's manifest), the run folder (KPIs, signals, the run in the measured-data format, JUnit), the
report and the 3D replay (``web/``)."""
