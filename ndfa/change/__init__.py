"""The paper's Sec. IV: object trees, association, registration, graph comparison, decisions. Pure numpy, no I/O."""
