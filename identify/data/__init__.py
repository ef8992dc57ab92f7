"""Measured data: runs (the CSV format), MATLAB .mat files, the one reader every command uses, preprocessing."""
