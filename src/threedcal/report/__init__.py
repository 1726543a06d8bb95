"""Study-wide outputs: the one-page summary and the run environment."""
