"""Data with known truth (model-class herds) and realistic synthetic cows with collar errors."""
