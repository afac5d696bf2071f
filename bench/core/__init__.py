"""The contract layer: what every other part of goniobench agrees on.

Roles (typed protocols every real or virtual device fills), geometry, errors, records and their
one JSON encoder, parsing of user inputs (ranges, wavelengths, TOML), calibration maths and the
conformance checker. It imports nothing else of the project; everything else imports it.
"""
