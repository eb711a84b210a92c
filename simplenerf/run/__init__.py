"""The run machinery around the method: what `simplenerf fit|validate|test|predict` builds and checks, and what keeps a
run safe and visible while it trains.

`cli` (the LightningCLI with the project's defaults: make_cli, load_for_tool, lightning_main)  `checks` (pre-flight
protocols, checkpoints, run folders)  `resume` (RunRecord: a resume continues the run)  `lock` (one writer per run
folder)  `signals` (SIGINT/SIGTERM: stop at a step's end)  `console` (one-line errors, quiet libraries)  `loggers`
(W&B, offline without credentials)  `memory` (SIMPLENERF_MALLOC)  `config_files` (the --config files given)
`hardware` (the CPU's capability; a slow precision's warning)  `callbacks/` (every callback a run uses, by what it
serves).
"""
