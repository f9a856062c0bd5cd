"""Command-line front ends: argument parsing, messages for people, process set-up. No library logic."""
