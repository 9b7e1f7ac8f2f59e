"""Co-simulation of a salmon singulation line: FMUs, scenarios, the master and the command line."""
