"""Self-contained HTML reports (``bench report``, ``bench diagnose --report``)."""
