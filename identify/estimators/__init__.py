"""The estimators (LS, IV, ML) around one segmented output-error engine, their result and plots."""
