"""app/reference: shipped reference cases (S1: the 40 x 60 mm free-form part, nine traces;
whole-board fixtures) and the evaluation against their truth (``evaluation``: standoff along
deposited moves, the line-width model, the seed's Table 1 rows)."""
