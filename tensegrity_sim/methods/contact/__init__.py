"""Contact, both methods: continuous member-contact detection and its events (``detection``), the ground's
detector (``ground``), the response with exact Coulomb friction (``friction``) and the member pairs' rows
(``member``)."""
from .detection import ActiveContact, ContactDetector, make_detector

__all__ = ["ActiveContact", "ContactDetector", "make_detector"]
