"""The validation gate every profile passes before it leaves the program.

:mod:`~planner.gate.requirements` (what a scenario demands, and the gate's tolerances),
:mod:`~planner.gate.drive_checks` (the robot-independent checks of any drive profile),
:mod:`~planner.gate.checks` (cabin8's full gate: workspace, forces, goal, approach, collision, sag) and
:mod:`~planner.gate.check_profile` (the use case behind CLI ``check`` and ``POST /plans:validate``).
"""
