"""Learning from measured data: re-simulating measured runs, residuals, evidence for each candidate
cause, the candidate registry, compare, diagnose and synthetic datasets with a known hidden effect."""
