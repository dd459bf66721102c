"""Direct transcriptions.

The ``k = 1`` collocation guess (its multipliers are the costates) and the bounded
B-spline solve used where joint limits bind; their tuning constants in :mod:`.tuning`.
"""
