"""Reading and aligning the measured data: recordings, bags, time base, gaps, edges, spans."""
