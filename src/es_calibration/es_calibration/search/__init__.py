"""The effect search: model states, each candidate's fit, selection, residual structure."""
