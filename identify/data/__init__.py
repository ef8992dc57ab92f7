"""Measured data: runs (the CSV format), MATLAB .mat files, the one reader every command uses (io),
the steps from a file's columns to runs (ingest: units, derived channels, time jitter and gaps), the
unit table (units), preprocessing."""
