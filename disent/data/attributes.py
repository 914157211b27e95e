"""The four binary face attributes every part of the suite shares (Sec. 5.2: the paper's edits)."""

ATTRIBUTES = ("smiling", "beard", "eyeglasses", "senior")
