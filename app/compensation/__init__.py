"""app/compensation (pure): trace standoff compensation (``standoff``) and the print paths it
writes (``print_path``).  Registration is in :mod:`app.registration`, surface fitting in
:mod:`app.reconstruction.surface_fit`, evaluation against the truth in :mod:`app.reference`."""
