"""Whole circuits from ECAD files, placed on the part, and existing programs warped onto it.

PURE core (no FastAPI, database, viewer or hardware):

* importers (``kicad``, ``gerber``, ``dxf``, ``svg``; ``formats.read_layout`` picks one)
  turn a file into a flat :class:`~app.circuits.layout.Layout` in mm: traces (exact NURBS
  curves with their source file, layer, net and width), pads and areas (polygons);
* ``placement`` moves the layout (origin, rotation, mirror) and ``mapping`` lays it on the
  part (``project``: vertical projection; ``wrap``: length-preserving geodesic unrolling);
* ``fills`` turns pads and areas into contour + raster paths at the line width;
* ``warp`` moves every printing move of a G-code program onto a measured surface with a
  chord bound proved against the height model (``height_model`` chooses that model from the
  probes by cross-validation and states its own error beside the bound).
"""
