"""Campaigns run: their cycles on the sweep executors, resumable, with the install order found or given."""
