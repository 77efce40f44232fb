"""The engine: options, plan, pairing, first guess, stages, solver, evaluation, report."""
