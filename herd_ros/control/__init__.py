"""Robot control laws and safety: herd-model following, velocity limits, fence, body-frame twist."""
