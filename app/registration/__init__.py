"""app/registration (pure): where the part really sits on the machine.

- ``registration``: the placement fit from datum touches (Gauss-Newton, covariance,
  observability) and :func:`~app.registration.registration.place_path` (a nominal trace
  moved into the machine frame); the placement itself is :class:`app.geometry.placement.Placement`
- ``datum_plan``: where to touch (D-optimal datum plans), edge finding with -Z touches,
  registration with a -Z probe
"""
