"""Plumbing shared by every package: errors, paths, node support, state files (imports nothing of the others)."""
