package org.evatar.client;

/** The pairings of the tests' nodes: PAIRING with credentials va-PAIRING (VA) and av-PAIRING (Avatar). */
final class Pairings {
    private Pairings() {}

    /** The PAIRING:AGENT_CREDENTIAL:AVATAR_CREDENTIAL specs of scripts/test-node.sh for these pairings. */
    static String[] specs(String... names) {
        String[] specs = new String[names.length];
        for (int i = 0; i < names.length; i++) {
            specs[i] = names[i] + ":va-" + names[i] + ":av-" + names[i];
        }
        return specs;
    }

    /** Options to join {@code pairing} on {@code node} with the role's credential. */
    static EvatarClient.Options opts(LocalNode node, String pairing, String role, String entity) {
        return new EvatarClient.Options().pairing(pairing).role(role).entityId(entity)
                .credential((role.equals("agent") ? "va-" : "av-") + pairing)
                .endpoint(node.host(), node.port());
    }
}
