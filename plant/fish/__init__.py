"""The fish: the paper's salmon data (``data/``: its Tables I-III), a fish as five rigid bodies with
contact spheres and outlines, the batch of a run (sampled or measured), and the candidate effects beyond
the paper's model (direction friction, mucus, rigor mortis, adhesion).  Imports nothing else of the plant
but :mod:`plant.errors` and :mod:`plant.validation`."""
