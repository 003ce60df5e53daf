"""app/gcode."""
