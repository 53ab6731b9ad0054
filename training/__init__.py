"""Training, evaluation and the command line of deck_sim (imports deck_sim; deck_sim never imports it)."""
