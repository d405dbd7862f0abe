"""The parts of a scenario run (``rig.runner.run_scenario`` puts them together): the plan,
the run on the bus or in process, pacing, what the rig hears, the evaluation, the outputs
and the typed result (``rig.run.result.RunResult``)."""
