"""Figures: tables in, figures out; never recompute physics here (style.md section 3)."""
