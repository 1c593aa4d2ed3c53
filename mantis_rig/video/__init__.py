"""The strike's video: its recordings read frame by frame (:mod:`.recording`), and the
markers found, named and followed in them (``docs/tracking_video.md``)."""
