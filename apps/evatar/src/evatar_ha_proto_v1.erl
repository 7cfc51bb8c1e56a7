%% @doc Internal. Version 1 of the messages EVATAR nodes exchange for high
%% availability: node heartbeats, inventories, standby placement, state
%% transfer (snapshot, event batches, confirmations), takeover, handover and
%% fencing checks. Every message between nodes is built and sent here and
%% has the shape `{evatar_ha, 1, Body}', so a node running a later version
%% can keep a `_proto_v1' module to talk to nodes not yet upgraded.
%%
%% Sends never set up a connection (`noconnect'): connections are made by
%% `evatar_cluster' alone, and a message lost to a broken connection is
%% covered by the failure detection (a gap in versions asks for a snapshot).
-module(evatar_ha_proto_v1).

-export([introduced_in/0, tag/0]).
-export([heartbeat/2, inventory/2, ask/3, instance/4, start_standby/5]).
-export([offer/3, snapshot/5, events/3, confirm/3, resync/3, dismiss/2, stale/3,
         handover/3, handover_done/4, peer_instance/2, rebalance/2]).
-export([vote/7, restore_vote/5, vote_reply/5, register/5, register_reply/5]).

-export_type([message/0, instance_info/0]).

-type instance_info() :: none | #{pid := pid(), role := atom(), epoch := pos_integer(),
                                  peer := pid() | undefined}.
-type repl_event() :: {Version :: pos_integer(), NowMs :: integer(),
                       evatar_pairing_logic:event()}.
-type body() :: {hb, node()}
              | {inventory, node(), [{evatar:pairing_id(), pid(), atom(), pos_integer()}]}
              | {ask, evatar:pairing_id(), pid()}
              | {instance, evatar:pairing_id(), node(), instance_info()}
              | {start_standby, evatar:pairing_id(), evatar_pairing_logic:config(), pid(),
                 pos_integer()}
              | {offer, pid(), non_neg_integer()}
              | {snapshot, pid(), pos_integer(), non_neg_integer(), evatar_pairing_logic:state(),
                 evatar_ha_core:claim()}
              | {events, pid(), pos_integer(), [repl_event()]}
              | {confirm, pid(), pos_integer(), non_neg_integer()}
              | {resync, pid(), non_neg_integer()}
              | {dismiss, pid()}
              | {stale, pid(), pos_integer()}
              | {handover, pid(), pos_integer(), non_neg_integer()}
              | {handover_done, pid(), pos_integer(), evatar_ha_core:claim()}
              | {vote, evatar:pairing_id(), pos_integer(), pid(), evatar_ha_core:claim(),
                 pid() | undefined, boolean()}
              | {restore_vote, evatar:pairing_id(), pos_integer(), pid(), [node()]}
              | {vote_reply, evatar:pairing_id(), pos_integer(), node(),
                 granted | {refused, evatar_ha_core:refusal()}}
              | {register, evatar:pairing_id(), pos_integer(), non_neg_integer(), pid()}
              | {register_reply, evatar:pairing_id(), evatar_ha_core:claim(), node(),
                 ok | {refused, evatar_ha_core:refusal()}}
              | {peer_instance, pid(), atom(), pos_integer()}
              | {rebalance, evatar_placement:move()}.
-type message() :: {evatar_ha, 1, body()}.

-define(M(Body), {evatar_ha, 1, Body}).

%% @doc The EVATAR version that introduced this protocol.
-spec introduced_in() -> string().
introduced_in() -> "0.2.0".

%% @doc The tag of every message of this version.
-spec tag() -> {evatar_ha, 1}.
tag() -> {evatar_ha, 1}.

%% --- between evatar_cluster processes --------------------------------------

%% @doc Node liveness, sent every `heartbeat_ms' to every connected peer.
-spec heartbeat(node(), node()) -> ok.
heartbeat(To, From) -> cluster(To, {hb, From}).

%% @doc This node's pairing instances, sent to a peer that (re)appears so
%% that instances of the same pairing can compare epochs.
-spec inventory(node(), [{evatar:pairing_id(), pid(), atom(), pos_integer()}]) -> ok.
inventory(To, Instances) -> cluster(To, {inventory, node(), Instances}).

%% @doc Asks node `To' which instance of `Id' it holds; the answer is an
%% {@link instance/4} message to `ReplyTo'.
-spec ask(node(), evatar:pairing_id(), pid()) -> ok.
ask(To, Id, ReplyTo) -> cluster(To, {ask, Id, ReplyTo}).

%% @doc The answer to {@link ask/3}.
-spec instance(pid(), evatar:pairing_id(), node(), instance_info()) -> ok.
instance(To, Id, Node, Info) -> pid(To, {instance, Id, Node, Info}).

%% @doc Asks node `To' to start a standby instance of `Id' for the active
%% `Active' (at `Epoch').
-spec start_standby(node(), evatar:pairing_id(), evatar_pairing_logic:config(), pid(),
                    pos_integer()) -> ok.
start_standby(To, Id, Config, Active, Epoch) ->
    cluster(To, {start_standby, Id, Config, Active, Epoch}).

%% @doc Tells a local or remote instance about another instance of its
%% pairing (from an inventory).
-spec peer_instance(pid(), {pid(), atom(), pos_integer()}) -> ok.
peer_instance(To, {Pid, Role, Epoch}) -> pid(To, {peer_instance, Pid, Role, Epoch}).

%% --- between the instances of one pairing ----------------------------------

%% @doc A new instance offers itself as the standby of the active `To'.
-spec offer(pid(), pid(), non_neg_integer()) -> ok.
offer(To, Standby, Version) -> pid(To, {offer, Standby, Version}).

%% @doc The active's whole state at `Version' (the standby replaces its own),
%% with the claim the standby holds from now on.
-spec snapshot(pid(), pos_integer(), non_neg_integer(), evatar_pairing_logic:state(),
               evatar_ha_core:claim()) -> ok.
snapshot(To, Epoch, Version, State, Claim) ->
    pid(To, {snapshot, self(), Epoch, Version, State, Claim}).

%% @doc Events in version order, each with the time it was applied at.
-spec events(pid(), pos_integer(), [repl_event()]) -> ok.
events(To, Epoch, Events) -> pid(To, {events, self(), Epoch, Events}).

%% @doc The standby has applied everything up to `Version'.
-spec confirm(pid(), pos_integer(), non_neg_integer()) -> ok.
confirm(To, Epoch, Version) -> pid(To, {confirm, self(), Epoch, Version}).

%% @doc The standby lost track (a gap, or its link came back): it holds
%% `Version' and asks for a snapshot.
-spec resync(pid(), pid(), non_neg_integer()) -> ok.
resync(To, Standby, Version) -> pid(To, {resync, Standby, Version}).

%% @doc The active no longer wants this standby: it stops.
-spec dismiss(pid(), pid()) -> ok.
dismiss(To, Active) -> pid(To, {dismiss, Active}).

%% @doc The sender holds a newer epoch: the receiver is stale and steps down.
-spec stale(pid(), pid(), pos_integer()) -> ok.
stale(To, From, Epoch) -> pid(To, {stale, From, Epoch}).

%% @doc Planned takeover: the active, fully confirmed at `Version', asks its
%% standby to take over.
-spec handover(pid(), pos_integer(), non_neg_integer()) -> ok.
handover(To, Epoch, Version) -> pid(To, {handover, self(), Epoch, Version}).

%% @doc The standby took over at `Epoch'; the old active becomes its standby
%% with `Claim'.
-spec handover_done(pid(), pid(), pos_integer(), evatar_ha_core:claim()) -> ok.
handover_done(To, From, Epoch, Claim) -> pid(To, {handover_done, From, Epoch, Claim}).

%% @doc The rebalancer asks active `To' for one move of its pairing
%% (evatar_placement); an active that cannot make it now ignores it.
-spec rebalance(pid(), evatar_placement:move()) -> ok.
rebalance(To, Move) -> pid(To, {rebalance, Move}).

%% --- votes: between an instance and every node's evatar_cluster ------------

%% @doc Instance `Cand' (holding `Claim') asks node `To' for pairing `Id' at
%% epoch `Ec'; `Active' is the active it followed (itself when a fenced
%% active asks again), `ActiveDead' whether it saw that process die (or
%% hand the pairing over).
-spec vote(node(), evatar:pairing_id(), pos_integer(), pid(), evatar_ha_core:claim(),
           pid() | undefined, boolean()) -> ok.
vote(To, Id, Ec, Cand, Claim, Active, ActiveDead) ->
    cluster(To, {vote, Id, Ec, Cand, Claim, Active, ActiveDead}).

%% @doc Instance `Cand', restored afresh, asks node `To' for pairing `Id'
%% at epoch `Ec'; the nodes `NoneOn' told it they run no instance of it.
%% Added after 0.2.0: a node that does not know it ignores it (grants
%% nothing), so a restore wins once a majority runs this version.
-spec restore_vote(node(), evatar:pairing_id(), pos_integer(), pid(), [node()]) -> ok.
restore_vote(To, Id, Ec, Cand, NoneOn) ->
    cluster(To, {restore_vote, Id, Ec, Cand, NoneOn}).

%% @doc A node's answer to {@link vote/7} and {@link restore_vote/5}.
-spec vote_reply(pid(), evatar:pairing_id(), pos_integer(), node(),
                 granted | {refused, evatar_ha_core:refusal()}) -> ok.
vote_reply(To, Id, Ec, Node, Result) -> pid(To, {vote_reply, Id, Ec, Node, Result}).

%% @doc The active `From' of `Id' asks node `To' to record its configuration
%% `{E, Seq}' (a standby dropped, or a takeover made).
-spec register(node(), evatar:pairing_id(), pos_integer(), non_neg_integer(), pid()) -> ok.
register(To, Id, E, Seq, From) -> cluster(To, {register, Id, E, Seq, From}).

%% @doc A node's answer to {@link register/5}.
-spec register_reply(pid(), evatar:pairing_id(), evatar_ha_core:claim(), node(),
                     ok | {refused, evatar_ha_core:refusal()}) -> ok.
register_reply(To, Id, Claim, Node, Result) ->
    pid(To, {register_reply, Id, Claim, Node, Result}).

%% ---------------------------------------------------------------------------

cluster(Node, Body) ->
    _ = erlang:send({evatar_cluster, Node}, ?M(Body), [noconnect]),
    ok.

pid(Pid, Body) ->
    _ = erlang:send(Pid, ?M(Body), [noconnect]),
    ok.
