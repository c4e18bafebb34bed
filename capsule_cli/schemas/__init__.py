"""Pydantic schemas of the study config, one module per stage."""
