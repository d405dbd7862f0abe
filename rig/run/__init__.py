"""A scenario run: ``runner.run_scenario`` runs it once (``single``) or over its own seeds
(``multi_seed``); a run's parts are the plan, the run on the bus or in process, pacing, what
the rig hears, the evaluation and the recording. Suites run here too (``suite``, in worker
processes: ``parallel``; over several noise seeds: ``seeds``).
"""
