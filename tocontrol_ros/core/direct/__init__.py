"""Direct transcriptions, and the direct methods of the contract.

The ``k = 1`` collocation guess (its multipliers are the costates) and the multistart's
guesses from it; the bounded B-spline solve used where joint limits bind; the first motion
(a seed path timed by TOPP-RA); :mod:`.method` puts the last two on the method contract
(``"direct"``, ``"first"``). Their tuning constants are in :mod:`.tuning`.
"""
