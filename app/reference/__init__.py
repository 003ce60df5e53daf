"""app/reference: shipped reference cases (S1: the 40 x 60 mm free-form part, nine traces)."""
