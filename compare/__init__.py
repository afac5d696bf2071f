"""Alignment of virtual and actual records, discrepancy statistics, physical checks, reports."""
