"""The joint core's supervision: stall detection and the deadman, run by the main loop."""

from .protocol import FLAG_BUSY, FLAG_NOTENABLED, FLAG_STALL


class Supervisor:
    """JointController's supervision (mixed into it)."""

    def _check_stall(self):
        if not self.stallguard or self.flags & (FLAG_STALL | FLAG_BUSY):
            return
        hal = self.hal
        rearms = self.stall_rearms
        stalled = self.stall.update(hal.pid_error(), hal.encoder_rpm(), self.qd_set)
        if self.trace is not None:
            self.trace(self.stall)
        if stalled and self._halt(FLAG_STALL, rearms=rearms):
            hal.stop(True)
            self.log.warn("stall detected (filtered error %.1f > threshold %.1f)"
                          % (self.stall.filtered, self.stall.threshold))

    def _check_deadman(self, now):
        """Velocity or position motion stops when the host has been silent too long."""
        if self.flags & (FLAG_NOTENABLED | FLAG_BUSY) or not (self.qd_set != 0 or self.positioning):
            return
        silent = self.clock.ticks_diff(now, self._last_host_ms)
        if silent > self.cfg.deadman_ms and self._halt(FLAG_NOTENABLED, transactions=self._seen_transactions):
            self.hal.set_rpm(0)
            self.log.warn("deadman: no I2C traffic for %d ms, motor stopped and disabled" % silent)
