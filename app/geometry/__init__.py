"""Pure geometry core (no web, database, viewer, hardware or file-system access).

- ``nurbs``: NurbsCurve (scipy BSpline on homogeneous coordinates; geomdl for exchange);
  ``nurbs_batch``: many curves evaluated together
- ``nurbs_surface``: NurbsSurface (scipy NdBSpline), inversion, normals, triangulation
- ``fitting``: interpolation (NURBS Book A9.1/A9.4), least squares (A9.6), smoothing, surface fits
- ``shapes``: API geometry dicts (line, arc, polyline, nurbs) -> NurbsCurve
- ``cl_points``: tool-location points within a verified chordal tolerance
- ``drape`` / ``edge_grid``: exact draping onto a faceted mesh's upper surface, snapping
- ``traces``: TracePolyline, the one trace polyline (and its stored JSON form), and
  build_nominal_trace, what the service calls to create a trace
- ``placement``: Placement, the one rigid placement part -> machine (apply, inverse, compose)
- ``slope``: surface slope under a trace and what a vertical nozzle can print
- ``tolerance``, ``errors``, ``validation``: the one tolerance home (Tolerance and the named
  thresholds), typed 422 errors, input checks
"""
