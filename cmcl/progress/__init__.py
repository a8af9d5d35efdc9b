"""What a run measures as it goes: episode rows and moving averages, learning progress, the training clock, rates."""
