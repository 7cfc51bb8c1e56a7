package org.evatar.client;

import java.io.IOException;
import java.time.Duration;
import java.util.List;
import java.util.concurrent.BlockingQueue;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.LinkedBlockingQueue;
import java.util.concurrent.TimeUnit;

/**
 * A VA's sensor emulator (paper, section 2.2): a component that provides a
 * SENSOR service the Avatar's sensor feeds with {@code SensorData}, and may
 * consume the sensor's reading service. Feed it the client's signals with
 * {@link #offer(Signal)} (it keeps those addressed to it).
 */
public class SensorEmulator extends ActuatorEmulator {
    private final BlockingQueue<Signal> readings = new LinkedBlockingQueue<>();

    public SensorEmulator(EvatarClient client, String component) {
        super(client, component);
    }

    /**
     * Keeps {@code s} when it is sensor data (or an entity's event) for this component; returns
     * whether it did. EVATAR's own events (RequestClosed, docs/protocol.md section 4.3) are not readings.
     */
    public boolean offer(Signal s) {
        if (s.receiver().equals(component) && !s.isFromEvatar()
                && (s.context().equals(Signal.SENSOR_DATA) || s.context().equals(Signal.EVENT))) {
            readings.add(s);
            return true;
        }
        return false;
    }

    /** The next reading, or null after {@code timeout}. */
    public Signal next(Duration timeout) throws InterruptedException {
        return readings.poll(timeout.toMillis(), TimeUnit.MILLISECONDS);
    }

    /** Asks the sensor for a reading (a SENSOR request such as ReadMotion); the feedback carries it. */
    public CompletableFuture<Signal> read(String type, List<Param> params) throws IOException {
        return request("SENSOR", type, params);
    }
}
