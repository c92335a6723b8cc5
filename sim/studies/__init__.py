"""Studies: runs of kernels whose results a report renders (validation, conformance, texture loops,
conversion). A study assembles, emulates and times through sim/timing and hands plain results to its
report in sim/reports, which only reads them; the report never imports its study."""
