"""The controller and its contexts: `JointController` (controller.py) and the code of each
context, IRQ (irq.py), main loop (loop.py, handlers.py), supervision (supervise.py) and blocking
tasks (tasks.py), with their boot-only builders (controller_init.py, irq_init.py). Who owns which
state is tabled in controller_init.py. May import spec, motion, detect and micro; never a link,
a backend (pico, sim) or hardware: the HAL, clock, logger and IRQ masking are injected."""
