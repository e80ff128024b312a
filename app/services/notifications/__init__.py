"""Alert notifications: an operator's webhook and e-mail channels (``channels``), deliveries
queued with the events the pipeline raises (``outbox``), and their sending with retries
(``sender``, over ``webhook`` and ``mail``)."""
