"""The paper's experiments: trials, metrics, tables and plots."""
