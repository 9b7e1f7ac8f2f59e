"""The candidate causes, one module each (:class:`fishfmu.analysis.candidate.Candidate`); the registry that lists
them is :data:`fishfmu.analysis.candidates.CANDIDATES`."""
