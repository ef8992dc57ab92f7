"""The estimators (LS, IV, ML) around one segmented output-error engine, frequency-domain equation
error (FDEE, batch and recursive), their result and plots."""
