"""The token kinds of a stream's section: ``tacit.codec.grammar`` writes and reads them (its table says
what each announces), ``tacit.codec.models`` keeps a token model per previous kind."""

END, STEP, SAME, JUMP, LOST, START, PHASE = range(7)
