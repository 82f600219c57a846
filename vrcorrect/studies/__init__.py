"""Layer 6, studies: what the project measures about its corrections, as a library the commands
call and the tests import. The paper's evaluation of every method on five refractive problems
(``evaluation``, its panels ``eval_panels``), simulated eye-chart acuity with each correction (``acuity_chart``), the benches,
each measuring one thing and writing its section of ``docs/benchmarks.md`` (``bench/``), and the
figures they draw (``plots``).

A study may use every layer below it (the physics, the solvers, the learned model, the real-time
library); it parses no command line and prints nothing but its progress: that is :mod:`vrcorrect.apps`.
Nothing heavy is imported at module level (the command line imports these to build its parser)."""
