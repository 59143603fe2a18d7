"""The application: planning a run, the run loop and resume, beds, outputs, metrics,
figures, trajectories, exports, films and the tools built on runs. Drives the engines;
no engine calls back into it."""
