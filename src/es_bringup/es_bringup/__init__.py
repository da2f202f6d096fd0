"""Bring-up and evaluation of the es_dm graph: launch, supervisor, demo and its report."""
