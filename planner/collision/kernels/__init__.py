"""Compiled (numba) kernels of the collision hot path.

By concern, each module importing only those above it:


* :mod:`.distances` -- exact segment, capsule-capsule and capsule-box distances;
* :mod:`.poses` -- body poses and the admissibility vector c(q) by the robot's own compiled kernel (its
  model's code and parameters, dispatched by :mod:`planner.robots.kernels`; cabin8's is closed form,
  paper eq. 4, MDH eq. 10-12), and the admissibility test;
* :mod:`.buffers` -- a world's constant data, built once (:func:`~.buffers.build`), packed into two flat
  buffers and read back by name (:class:`~.buffers.Packed`);
* :mod:`.bounds` -- certified lower bounds from sphere covers (all at once or one by one) and certain
  contacts from the grid's upper bound;
* :mod:`.obstacles` -- the obstacles' bounds (bounding spheres and fine covers against the obstacles'
  bounding boxes), from an obstacle set's own packed data (:func:`~.buffers.obstacle_data`);
* :mod:`.offsets` -- how far bodies move between poses, and a run's vertices from their chords;
* :mod:`.state` -- one state check in one call (poses, bounds, verdict code);
* :mod:`.walk` -- the certified motion walk, resumable around the FCL probes that stay in Python.

The Python side calls them through :mod:`.entries` (arguments checked), which runs their ahead-of-time
build (:mod:`planner.core.aot`: an extension module keyed by a hash of these sources, so an edit makes a
new build) or, without one, numba's JIT. :mod:`.buffers` and :mod:`.codes` import no numba.

Under the JIT, every kernel is compiled with ``cache=True`` (numba's on-disk cache next to these files).
Numba checks a cached function against its own file only: after editing one of these modules, delete
``planner/collision/kernels/__pycache__`` (and ``planner/robots/__pycache__`` after editing a robot's
kernel) so that the kernels of the other modules that call into it are compiled again.
"""
