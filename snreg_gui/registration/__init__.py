"""The Registration tab: preop and intraop nodes, method, bounds and initial alignment, the run, pairing and exports."""
