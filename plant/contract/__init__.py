"""The measured-data and KPI contract (docs/measured-data.md, docs/kpis.md): the line as a dataset or a
scenario describes it, the format of a measured run, its physical plausibility, passages at a beam and the
KPIs.  A simulated run is written in the same format and goes through the same readers and KPI code as a
measured one.  Imports the fish (sizes, regressions), never the simulation."""
